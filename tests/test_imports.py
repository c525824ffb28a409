"""The import graph between floors (STYLE.md 2: lower floors never import upper ones; eval/ never
imports gspi/). Every import statement of every module is read from its AST, including imports
inside functions, so a lazy import cannot hide an upward edge. Under tests/, no module imports
from a test module (shared helpers live in helper modules such as tests/fixtures.py).
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("eval", "gspi", "baselines", "experiments")
PRODUCT = ("eval", "gspi", "baselines")  # experiments/ (the studies) sits above them all

LOWER = ("eval", "eval.common", "gspi.repo", "gspi.strict_config", "gspi.device", "gspi.data", "gspi.gaussians",
         "gspi.point_cloud", "gspi.light")
STAGE = LOWER + ("gspi.stage_clock",)
# floor -> the floors (or modules) it may import besides itself. A floor missing here fails the
# test: a new gspi subpackage or top-level module must be placed in the graph on purpose.
ALLOWED: dict[str, tuple[str, ...]] = {
    # the common floor: layout, image and colour I/O, atomic records, stated errors, the CLI door,
    # the device, the npm fetcher (issue 67); below the protocol, it imports nothing of the project
    "eval.common": (),
    "eval": ("eval.common",),  # the protocol
    "gspi": (),  # gspi/__init__.py
    "gspi.strict_config": ("eval.common",),  # eval.common.errors: ConfigError is a stated error
    "gspi.device": ("eval.common",),  # device=auto|cpu|cuda (issue #16): re-exports eval.common.device
    "gspi.stage_clock": (),
    "gspi.repo": (),  # the repository root, resolved once
    "gspi.data": ("eval", "eval.common", "gspi.strict_config"),
    "gspi.gaussians": ("eval", "eval.common", "gspi.data"),
    # Stage I's output record (points with their source pixels) and its scatter/fill, read by
    # Stages II and III: a record between stages lives below them, not in Stage I's package.
    "gspi.point_cloud": ("eval", "eval.common", "gspi.data"),
    # the capture light and each point's material read against it (issue 66): the shader's math
    # over observations, read by Stage II's conditions and the light_fit method
    "gspi.light": ("eval", "eval.common"),
    "gspi.recon": LOWER,
    "gspi.stage1": LOWER,
    "gspi.stage2": LOWER,  # no stage imports another stage
    "gspi.stage3": LOWER,
    "gspi.relight": LOWER,
    # the glTF export of a PBR-GS asset; its round trip compares with Stage III's material renders
    # (what gspi-run predicts and gspi-eval scores), so it reads them from Stage III
    "gspi.export": LOWER + ("gspi.stage3",),
    "gspi.pipeline": STAGE + ("gspi.stage1", "gspi.stage2", "gspi.stage3"),
    "baselines": LOWER + ("gspi.recon",),
    "gspi.run": STAGE + ("gspi.recon", "gspi.stage1", "gspi.stage2", "gspi.stage3", "gspi.pipeline",
                         "gspi.relight", "gspi.export", "baselines"),
    # gspi-reproduce (issue 53) runs the tools as commands, one subprocess per step: it imports none
    "gspi.reproduce": ("eval", "eval.common", "gspi.repo"),
    # make results: the results store (results/) and the docs' tables built from it by eval.tables
    "gspi.publish": ("eval", "eval.common", "gspi.repo", "gspi.data"),  # gspi.data: the controlled pairs' members
    "gspi.cli": STAGE + ("gspi.recon", "gspi.stage1", "gspi.stage2", "gspi.stage3", "gspi.pipeline",
                         "gspi.relight", "gspi.export", "gspi.run", "gspi.reproduce", "baselines"),
    # the studies (issue 40): they use the product; nothing in the product imports them
    "experiments": ("eval", "eval.common", "gspi", "baselines"),
}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_names(path: Path) -> list[tuple[str, int]]:
    """(dotted name, line) of every import in ``path``; ``from a import b`` gives ``a`` and ``a.b``."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module
            found.append((module, node.lineno))
            found += [(f"{module}.{alias.name}", node.lineno) for alias in node.names]
    return found


def floor(name: str) -> str | None:
    """The floor of a dotted module name: eval.common, eval, baselines, gspi.<first part>; None outside
    the project."""
    parts = name.split(".")
    if parts[:2] == ["eval", "common"]:
        return "eval.common"
    if parts[0] in ("eval", "baselines", "experiments"):
        return parts[0]
    if parts[0] == "gspi":
        return ".".join(parts[:2])
    return None


def is_allowed(src: str, target: str) -> bool:
    return floor(target) == src or any(target == a or target.startswith(a + ".") for a in ALLOWED[src])


def project_modules() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))


def test_the_product_imports_nothing_from_the_studies():
    """gspi/, eval/ and baselines/ never import experiments/ (issue 40), lazily or not."""
    bad = [f"{p.relative_to(ROOT)}:{line} imports {name}" for pkg in PRODUCT for p in (ROOT / pkg).rglob("*.py")
           for name, line in imported_names(p) if name.split(".")[0] == "experiments"]
    assert not bad, bad


def test_every_floor_is_placed_in_the_graph():
    floors = {floor(module_name(p)) for p in project_modules()}
    assert floors - set(ALLOWED) == set(), "add these floors to ALLOWED on purpose"


def test_scanner_sees_function_level_and_relative_imports(tmp_path):
    # pipeline.py imports the stages inside run_gspi_scene only
    names = [n for n, _ in imported_names(ROOT / "gspi" / "pipeline.py")]
    assert "gspi.stage3.distill.distill" in names
    assert not is_allowed("eval", "gspi.data.lattice") and not is_allowed("gspi.stage1", "gspi.run.record")
    assert is_allowed("eval", "eval.common.layout") and not is_allowed("eval.common", "eval.relight")
    assert not is_allowed("eval.common", "eval.config") and floor("eval.common.cli_entry") == "eval.common"
    assert not is_allowed("gspi.stage2", "gspi.stage1.extract") and is_allowed("gspi.stage2", "gspi.point_cloud")
    assert not is_allowed("gspi.stage3", "gspi.stage1") and not is_allowed("gspi.stage3", "gspi.stage2")
    assert is_allowed("gspi.run", "gspi.pipeline") and not is_allowed("gspi.pipeline", "gspi.run.stage2_model")


@pytest.mark.parametrize("path", project_modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_imports_point_down(path):
    src = floor(module_name(path))
    bad = [f"{path.relative_to(ROOT)}:{line} imports {name}" for name, line in imported_names(path)
           if floor(name) is not None and not is_allowed(src, name)]
    assert not bad, f"{src} may import only {ALLOWED[src]}:\n" + "\n".join(bad)


# The floors inside gspi/data (gspi/data/__init__.py), lowest first: the shared facts, the
# procedural benchmark, the rooms built on it, and the dataset writer on top (issue 54). A module
# may import its own floor and those below; every gspi.data module must be placed here.
DATA_FLOORS: tuple[tuple[str, ...], ...] = (
    ("gspi.data.lattice", "gspi.data.environments", "gspi.data.pmndrs_assets", "gspi.data.hdri",
     "gspi.data.point_clouds", "gspi.data.gt_maps", "gspi.data.contact_sheet", "gspi.data.layouts"),
    ("gspi.data.procedural",),
    ("gspi.data.env_sets", "gspi.data.assets", "gspi.data.pool", "gspi.data.controlled_pairs"),
    ("gspi.data.generate",),
)


def data_floor(name: str) -> int | None:
    """Index in DATA_FLOORS of a gspi.data module (None for the package itself or outside it)."""
    for level, prefixes in enumerate(DATA_FLOORS):
        if any(name == p or name.startswith(p + ".") for p in prefixes):
            return level
    return None


def test_every_gspi_data_module_has_a_floor():
    names = [module_name(p) for p in (ROOT / "gspi" / "data").rglob("*.py")]
    assert [n for n in names if n != "gspi.data" and data_floor(n) is None] == []


def test_imports_inside_gspi_data_point_down():
    """hdri -> assets.pmndrs_assets and assets.glb_import -> generate ran upward before issue 54."""
    assert data_floor("gspi.data.assets.glb_import") < data_floor("gspi.data.generate")
    assert data_floor("gspi.data.hdri") < data_floor("gspi.data.assets.pathtrace")
    bad = []
    for path in sorted((ROOT / "gspi" / "data").rglob("*.py")):
        src = data_floor(module_name(path))
        for name, line in imported_names(path):
            target = data_floor(name)
            if src is not None and target is not None and target > src:
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {name} (floor {target} > {src})")
    assert not bad, "\n".join(bad)


def module_graph() -> dict[str, set[str]]:
    """module -> the project modules it imports (function-level imports included)."""
    paths = {module_name(p): p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in paths.items():
        edges = set()
        for target, _ in imported_names(path):
            while target and target not in paths:  # `from a.b import c`: c may be a name in a.b
                target = target.rpartition(".")[0]
            if target and target != name and not name.startswith(target + "."):  # a package's own __init__
                edges.add(target)
        graph[name] = edges
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    import sys
    sys.setrecursionlimit(10000)
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_cycle_finder_finds_a_planted_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycles_anywhere():
    """No module reaches itself through imports, inside a package too (issue 25)."""
    assert cycles(module_graph()) == []


def modules_under_tests() -> dict[str, Path]:
    """Every module under tests/ (test modules, helper modules, conftests, the golden recorders)."""
    return {module_name(p): p for p in sorted((ROOT / "tests").rglob("*.py"))}


def imported_test_module(name: str, modules: dict[str, Path]) -> str | None:
    """The test module (tests/**/test_*.py) that the imported dotted ``name`` is or lies in, else None."""
    while name and name not in modules:  # `from a.b import c`: c may be a name in a.b
        name = name.rpartition(".")[0]
    return name if name and name.rpartition(".")[2].startswith("test_") else None


def test_no_module_under_tests_imports_a_test_module():
    """Helpers shared by test modules live in helper modules (tests/fixtures.py,
    tests/stage2_fixtures.py, ...), never in a test module: importing from one makes a test file a
    library and runs its module-level code and fixtures in another file's collection (issue 25)."""
    modules = modules_under_tests()
    assert imported_test_module("tests.test_stage2_data.SIZE", modules) == "tests.test_stage2_data"
    assert imported_test_module("tests.reliability.test_paths", modules) == "tests.reliability.test_paths"
    assert imported_test_module("tests.stage2_fixtures.make_lattice_scene", modules) is None
    assert imported_test_module("tests.fixtures", modules) is None and imported_test_module("torch", modules) is None
    bad = sorted({f"{path.relative_to(ROOT)}:{line} imports from {target}" for path in modules.values()
                  for name, line in imported_names(path) if (target := imported_test_module(name, modules))})
    assert not bad, "move the shared helpers to a helper module under tests/:\n" + "\n".join(bad)


ATOMIC_WRITERS = ("atomic_path", "write_text_atomic", "write_json_atomic")


def test_the_atomic_writers_have_one_door():
    """Everyone imports the atomic writers from eval.common.atomic, never through a re-export (issue 25)."""
    files = [p for pkg in (*PACKAGES, "tests", "benchmarks") for p in sorted((ROOT / pkg).rglob("*.py"))]
    bad = sorted(f"{p.relative_to(ROOT)}:{line} imports {name}" for p in files for name, line in imported_names(p)
                 if name.rpartition(".")[2] in ATOMIC_WRITERS and name.rpartition(".")[0] != "eval.common.atomic")
    assert not bad, "import the atomic writers from eval.common.atomic:\n" + "\n".join(bad)


def test_eval_is_in_rooms():
    """eval/'s sub-packages stand for what the old name prefixes did (tables_*, lpips_*, *_folders)."""
    flat = sorted(p.name for p in (ROOT / "eval").glob("*.py")
                  if p.stem.startswith(("tables_", "lpips_", "points_folders", "eval_folders", "run_record"))
                  or p.stem in ("tables", "report"))
    assert not flat, f"eval/ modules outside their rooms: {flat}"
    for room in ("tables", "lpips", "records", "report_site"):
        assert (ROOT / "eval" / room / "__init__.py").is_file(), room


def test_gitignore_covers_the_venv_link_and_readme_outputs(tmp_path):
    """A `.venv` symlink (a shared environment) and README's `data/` and `runs/` are ignored; the
    test fixtures under tests/data stay tracked (issue 54)."""
    import shutil
    import subprocess

    if shutil.which("git") is None:
        pytest.skip("git not installed")
    paths = [".venv", "data/small/splits.json", "runs/gspi/result.json", "tests/data/ply/x.ply"]
    proc = subprocess.run(["git", "-C", str(ROOT), "check-ignore", "--no-index", *paths],
                          capture_output=True, text=True)
    assert proc.stdout.split() == paths[:3], proc.stdout + proc.stderr

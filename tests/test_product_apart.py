"""The product apart from the studies (style guide principle 10, issue 67): a study is a folder you
can delete.

The rule, checked here:
- The product is gspi/, eval/, baselines/, benchmarks/, conf/, tests/, the Makefile, README.md,
  pyproject.toml, .ci/, the results store (results/) and the docs (docs/*.md and the generated
  docs/results/*.md). docs/log/ is
  the diary: it keeps the dated history, the studies' included, and is not checked.
- A study that stands apart (its folder holds a README.md: its findings and commands) is named
  nowhere in the product: not its folder (``experiments/<study>``, ``experiments.<study>``), not its
  name, not a config it defines (the file names under its ``conf/``, the ``scale`` of its reproduce
  files), not the product's former path of a checkpoint it keeps (``checkpoints/<file>`` of a file in
  its ``checkpoints/``: a retired model, issue 67; a table may still report the model's scores by
  name, and a score file under results/ keeps the path its model had when it was measured). Only the convention is named (``experiments/<study>/conf``, ``study=<name>``).
- The studies not yet moved apart are named only where ``NOT_YET_APART`` says (issue 67's rest):
  the list may shrink, never grow.
- Every product reproduce file is a table or a shipped model at a size (``table<N>_<smoke|cpu>``,
  ``model_<name>_<smoke|cpu>``) and dry-runs.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
STUDIES = ROOT / "experiments"
PRODUCT = ("gspi", "eval", "baselines", "benchmarks", "conf", "tests", ".ci", "Makefile", "README.md",
           "pyproject.toml", "docs/*.md", "docs/results/*.md", "results")
TEXT = {".py", ".yaml", ".yml", ".md", ".toml", ".sh", ".txt", ".cfg", ".json", ""}
SIZES = ("smoke", "cpu")
# product file -> the studies it still names; each is issue 67's work left (move the study apart)
NOT_YET_APART: dict[str, set[str]] = {}  # empty since issue 67: no study the product names is left


def product_files() -> list[Path]:
    files = []
    for pattern in PRODUCT:
        for path in sorted(ROOT.glob(pattern)):
            files += [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    me = Path(__file__).resolve()
    return [p for p in files if p.suffix in TEXT and p.resolve() != me and "__pycache__" not in p.parts]


def studies() -> list[Path]:
    return sorted(p for p in STUDIES.glob("*") if p.is_dir() and (p / "__init__.py").is_file())


def apart(study: Path) -> bool:
    return (study / "README.md").is_file()


def study_keys(study: Path) -> set[str]:
    """What names the study: its name, its config file names, its reproduce scales (``scale=`` for
    a one-word scale, which may be an ordinary word), the product path its checkpoints had."""
    keys = {study.name} | {f"checkpoints/{p.name}" for p in (study / "checkpoints").glob("*") if p.is_file()}
    for path in (study / "conf").rglob("*.yaml"):
        keys.add(path.stem)
        if path.parent.name == "reproduce":
            scale = str((yaml.safe_load(path.read_text()) or {}).get("scale", ""))
            keys.add(scale if "_" in scale else f"scale={scale}")
    return keys - {"scale="}


def named_studies(text: str) -> set[str]:
    names = {p.name for p in studies()}
    return {m for m in re.findall(r"experiments[/.](\w+)", text) if m in names}


@pytest.fixture(scope="module")
def texts() -> dict[str, str]:
    out = {}
    for path in product_files():
        try:
            out[str(path.relative_to(ROOT))] = path.read_text()
        except UnicodeDecodeError:
            continue
    return out


def test_the_check_sees_the_product_and_the_studies(texts):
    assert {"gspi/cli/reproduce.py", "Makefile", "docs/STAGE2.md", "conf/gspi_reproduce.yaml"} <= set(texts)
    assert not any(name.startswith(("docs/log/", "experiments/")) for name in texts)


def test_the_product_names_no_study_that_stands_apart(texts):
    found = []
    for study in filter(apart, studies()):
        pattern = re.compile("|".join(rf"(?<![\w-]){re.escape(k)}(?![\w])" for k in sorted(study_keys(study))))
        found += [f"{name}: {m.group(0)!r} ({study.name})" for name, text in texts.items()
                  for m in pattern.finditer(text) if not (name.startswith("results/") and m.group(0).startswith("checkpoints/"))]
        # (a committed score file records the path its model had when it was measured)
    assert not found, "the product names a study (principle 10): " + "; ".join(found[:20])


def test_a_studys_checkpoints_are_among_its_keys(tmp_path):
    """A study's retired models (issue 67): their former product paths name the study, as its
    configs do (a made-up study: the check holds with experiments/ deleted)."""
    study = tmp_path / "some_study"
    (study / "conf" / "stage2").mkdir(parents=True)
    (study / "checkpoints").mkdir()
    (study / "conf" / "stage2" / "cpu_old.yaml").write_text("checkpoint: some_study/checkpoints/stage2_old.pt\n")
    for name in ("stage2_old.pt", "stage2_old.json"):
        (study / "checkpoints" / name).write_text("x")
    assert study_keys(study) == {"some_study", "cpu_old", "checkpoints/stage2_old.pt", "checkpoints/stage2_old.json"}


def test_the_studies_not_yet_apart_are_named_only_where_listed(texts):
    extra = {}
    for name, text in texts.items():
        more = named_studies(text) - NOT_YET_APART.get(name, set())
        if more:
            extra[name] = sorted(more)
    assert not extra, f"the product names a study's folder (principle 10): {extra}"
    assert not any(apart(STUDIES / s) for studies_ in NOT_YET_APART.values() for s in studies_), \
        "a study moved apart: remove it from NOT_YET_APART"


REPRODUCE = sorted((ROOT / "conf" / "reproduce").glob("*.yaml"))


def test_a_product_reproduce_file_is_a_table_at_a_size():
    sizes = "|".join(SIZES)
    bad = [p.name for p in REPRODUCE if not re.fullmatch(rf"(table\d|model_[a-z0-9]+)_({sizes})\.yaml", p.name)]
    assert REPRODUCE and not bad, f"conf/reproduce holds only table<N>_<size> or model_<name>_<size> ({SIZES}): {bad}"


@pytest.mark.parametrize("path", REPRODUCE, ids=[p.stem for p in REPRODUCE])
def test_every_product_reproduce_file_dry_runs(path, tmp_path, capsys):
    from gspi.cli import reproduce as cli

    assert cli.main([*cli.call_name(path.stem).split(), f"data_root={tmp_path}", "dry_run=true"]) == 0
    out = capsys.readouterr().out
    assert "step(s) to do" in out or "nothing left to do" in out
    assert not any(tmp_path.iterdir())  # a dry run writes nothing

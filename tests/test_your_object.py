"""docs/YOUR_OBJECT.md runs as written (issue 68): each path's fenced block, in order, from a
folder holding the user's file, on a tiny object.

The page's commands are run through each console script's ``main()`` with only the sizes made
tiny (``preset=small`` -> ``tiny``, ``recon=fast`` -> ``tiny``, plus the tiny stage options and
smaller relight and export settings); every path, key and file name is the page's. Path A (a GLB,
the fast path) runs by default; B (a splat PLY with its photos) and C (photos with cameras alone)
are slow. Their inputs are made from the GLB: its imported scene exported as a NeRF-synthetic
folder (``my_capture``) and, for B, a 2DGS PLY fitted to it by gspi-recon (``my_splats.ply``).
"""
from __future__ import annotations

import json
import re
import shlex
import shutil
import tomllib
from importlib import import_module
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "YOUR_OBJECT.md"
FENCE = re.compile(r"```[a-z]*\n(.*?)```", re.S)
SIZES = {  # appended to each program's line: the page's commands at test size
    "gspi-run": ["stage1=tiny", "stage1.image_size=64", "stage3=tiny", "logger=none"],
    "gspi-relight": ["frames=2", "size=64"],
    "gspi-export": ["export.mesh.image_size=64", "export.mesh.resolution=24", "export.texture.size=64"],
    "gspi-report": ["max_views=1"],
    "gspi-recon": ["recon=tiny"],
}
REPLACE = {"preset=small": "preset=tiny", "recon=fast": "recon=tiny"}


def section_commands(heading: str) -> list[str]:
    """The command lines of the first fenced block under the ``## <heading>...`` section."""
    text = PAGE.read_text()
    start = text.index(f"\n## {heading}")
    end = text.find("\n## ", start + 1)
    block = FENCE.search(text[start:end if end > 0 else None]).group(1)
    return [line.strip() for line in block.splitlines() if line.strip()]


def at_test_size(line: str) -> list[str]:
    """``line`` as argv (program first) with the sizes made tiny (``SIZES``, ``REPLACE``)."""
    argv = [REPLACE.get(a, a) for a in shlex.split(line)]
    return argv + SIZES.get(argv[0], [])


def run_line(line: str) -> None:
    from tests.reliability.helpers import run_cli

    argv = at_test_size(line)
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    module, _, name = scripts[argv[0]].partition(":")
    if argv[0] in ("gspi-run", "gspi-eval"):
        from eval.config import register_configs

        register_configs()  # what their main() does before Hydra
    code, text = run_cli(getattr(import_module(module), name), argv[1:])
    assert code == 0, f"`{line}` exit {code}:\n{text[-3000:]}"


def sphere_glb(path: Path) -> Path:
    """A small PBR sphere (a dielectric, roughness 0.5), the user's GLB."""
    trimesh = pytest.importorskip("trimesh")
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    material = trimesh.visual.material.PBRMaterial(baseColorFactor=np.array([0.8, 0.3, 0.2, 1.0]),
                                                   roughnessFactor=0.5, metallicFactor=0.0)
    mesh.visual = trimesh.visual.TextureVisuals(material=material)
    path.write_bytes(mesh.export(file_type="glb"))
    return path


def assert_outputs(run: Path, scene: str) -> None:
    """The page's promised outputs: the PBR-GS asset, its relit turntable, its GLB, the report."""
    assert (run / "work" / scene / "pbr_gs.ply").is_file()
    assert (run / "relight" / scene / "relight.json").is_file()
    assert (run / "export" / scene / "pbr_gs.glb").is_file()
    assert (run / "report" / "index.html").is_file()


def test_the_page_has_its_three_paths_and_links_from_readme():
    assert len(section_commands("A. A GLB")) == 5
    assert section_commands("B. A 2DGS or 3DGS PLY")[1].endswith("assets=my_splats.ply")
    assert "recon=fast" in section_commands("C. Photos")[1]
    assert "docs/YOUR_OBJECT.md" in "\n".join((ROOT / "README.md").read_text().splitlines()[:12])


def test_path_a_a_glb_runs_as_written(tmp_path, monkeypatch):
    sphere_glb(tmp_path / "my_object.glb")
    monkeypatch.chdir(tmp_path)
    for line in section_commands("A. A GLB"):
        run_line(line)
    assert_outputs(tmp_path / "run", "my_object")
    assert (tmp_path / "run" / "eval" / "summary.json").is_file()


def capture_from_glb(tmp_path: Path) -> None:
    """``my_capture``: the GLB's scene, imported at test size, as a NeRF-synthetic folder."""
    sphere_glb(tmp_path / "my_object.glb")
    run_line("gspi-data import.glb=my_object.glb out=glb_scene preset=small")
    run_line("gspi-data export.src=glb_scene/my_object export.format=nerf_synthetic out=my_capture")
    for split in ("train", "val", "test"):  # a user's folder carries no scene name: the folder's is used
        path = tmp_path / "my_capture" / f"transforms_{split}.json"
        if path.is_file():
            frames = json.loads(path.read_text())
            frames.get("gspi", {}).pop("name", None)
            path.write_text(json.dumps(frames))


@pytest.mark.slow
def test_path_b_a_splat_ply_with_its_photos_runs_as_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    capture_from_glb(tmp_path)
    lines = section_commands("B. A 2DGS or 3DGS PLY")
    run_line(lines[0])  # the import
    run_line("gspi-recon scene=obj_b/my_capture out=recon")  # the page's "No PLY yet" line
    shutil.copy(tmp_path / "recon" / "point_cloud.ply", tmp_path / "my_splats.ply")
    for line in lines[1:]:
        run_line(line)
    assert_outputs(tmp_path / "run_b", "my_capture")


@pytest.mark.slow
def test_path_c_photos_with_cameras_alone_run_as_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    capture_from_glb(tmp_path)
    for line in section_commands("C. Photos"):
        run_line(line)
    assert_outputs(tmp_path / "run_c", "my_capture")

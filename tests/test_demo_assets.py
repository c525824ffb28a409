"""The 2DGS assets shipped for `make demo` (checkpoints/demo_assets): readable, one per test
scene of the `small` preset, made with the `recon=fast` config that conf/ holds today."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from gspi.gaussians.ply import read_ply
from gspi.run.assets import user_asset_path

ROOT = Path(__file__).resolve().parents[1]
ASSETS = ROOT / "checkpoints" / "demo_assets"
SCENES = sorted(p.name for p in ASSETS.iterdir() if p.is_dir())


def test_one_asset_per_small_test_scene():
    assert SCENES == ["s002_multipart_ceramic", "s004_superquadric_metal", "s006_blob_glossy_plastic",
                      "s015_capsule_fabric"]


@pytest.mark.parametrize("scene", SCENES)
def test_asset_reads_and_is_a_plain_2dgs_asset(scene, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the relative path is read from the repository root
    path = user_asset_path("checkpoints/demo_assets", scene, num_scenes=4)
    assert path.resolve() == (ASSETS / scene / "point_cloud.ply").resolve()
    asset = read_ply(path)
    recorded = json.loads((ASSETS / scene / "recon.json").read_text())
    assert asset.num_gaussians == recorded["num_gaussians"] and not asset.has_pbr
    for tensor in (asset.means, asset.log_scales, asset.opacity_logits, asset.sh_dc):
        assert torch.isfinite(tensor).all()


def test_recorded_config_is_recon_fast():
    from eval.config import register_configs

    register_configs()
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose("gspi_run", overrides=["data_dir=x", "recon=fast"])
    fast = OmegaConf.to_container(cfg.recon, resolve=True)
    for scene in SCENES:
        recorded = json.loads((ASSETS / scene / "recon.json").read_text())
        assert recorded["scene"] == scene and recorded["config"] == fast, scene

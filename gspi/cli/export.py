"""gspi-export: a PBR-GS asset as a relightable glTF 2.0 file (``asset=``); with ``system=`` the
canonical scene written as an external system's input folder (baselines.cli, docs/BASELINES.md).

    gspi-export asset=runs/method=gspi/work/s002/pbr_gs.ply out=asset.glb
    gspi-export asset=.../pbr_gs.ply out=asset.glb export.texture.size=1024 export.preview=false
    gspi-export system=gs_ir scene=data/small/s002_multipart_ceramic out=exports/gs_ir/s002

The GLB: the 2DGS surface as a triangle mesh (TSDF fusion of the lattice depth renders), a UV
atlas (xatlas) and base-colour and metallic-roughness textures baked from the surfels' PBR
attributes, plus ``<stem>_preview.png`` beside it (gspi/export/, docs/EXPORT.md; config
conf/gspi_export_asset.yaml; a bad asset is one line naming the file, exit 2). It prints one
progress line per step (mesh, UV atlas, textures, GLB, preview: what each made and its seconds)
and a summary line.
"""
from __future__ import annotations

import sys
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from eval.common.cli_entry import hydra_cli

ASSET_KEY = "asset="


def run_asset_export(cfg: DictConfig) -> dict:
    """`gspi-export asset=... out=...`: the GLB export (module docstring); returns its record."""
    import torch

    from gspi.export.asset import export_asset
    from gspi.export.config import ExportConfig
    from gspi.strict_config import check_value

    torch.set_num_threads(check_value("threads", cfg.threads, int, lo=1, hi=1024))
    export_cfg = ExportConfig.from_dict(OmegaConf.to_container(cfg.export, resolve=True))
    return export_asset(Path(cfg.asset), Path(cfg.out), export_cfg)  # a progress line per step, then a summary


export_asset_main = hydra_cli(run_asset_export, "gspi_export_asset", path_keys=("asset", "out"))


def is_asset_export(argv: list[str]) -> bool:
    """The command line asks for the GLB export: it has `asset=` and no `system=`/`method=`."""
    return any(a.startswith(ASSET_KEY) for a in argv) and not any(a.startswith(("system=", "method=")) for a in argv)


def main() -> None:
    """`gspi-export`: the GLB export with `asset=`, else a system's input folder (`system=`)."""
    if is_asset_export(sys.argv[1:]):
        export_asset_main()
    else:
        from baselines.cli import export_system_main

        export_system_main()


if __name__ == "__main__":
    main()

"""Per-stage times of GS-PI on one demo scene, and GS-PI vs joint IR material time, in one run.

The demo's settings (conf/experiment/demo.yaml: the shipped ``recon=fast`` asset, the default
Stage II checkpoint at 10 DDIM steps, 100 Stage III iterations), one scene, one thread: ``gspi-run`` runs
``method=gspi`` and then ``method=joint_ir`` one after the other in fresh processes, and the
times come from what the runs recorded (``predictions/<scene>/meta.json``: the StageClock of
each stage; material time = Stage I + II + III + render for GS-PI, the optimisation for joint
IR, as Table 1 counts them). Inside GS-PI's stages: Stage I's render / filters split
(``stage1.json``) and Stage III's seconds per iteration (``stage3.json``).

Data: ``--data`` (a ``small`` test set, e.g. ``demo_out/data`` after ``make demo``); without it
the demo's data are generated into a temp folder first (``gspi-data preset=small seed=0
'data.only_splits=[test]'``, ~1 min).

    python -m benchmarks.bench_pipeline [--data demo_out/data] [--scene s004_superquadric_metal]
    python -m benchmarks.bench_pipeline --preset tiny   # a `tiny` scene (64 px), its asset made by recon=tiny

``--preset tiny``: the issue's other scale (``gspi-data preset=tiny seed=0``, its first test scene);
there is no shipped asset, so each run reconstructs it (``recon=tiny``, counted apart from the
material time, as Table 1 counts Stage 0); the rest of the demo's settings as above.
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

from benchmarks.common import REPO, command_seconds, machine


def demo_overrides() -> list[str]:
    """The demo's settings as gspi-run overrides, read from conf/experiment/demo.yaml (its one definition)."""
    import yaml

    demo = yaml.safe_load((REPO / "conf" / "experiment" / "demo.yaml").read_text())
    recon = next(d["override /recon"] for d in demo["defaults"] if isinstance(d, dict) and "override /recon" in d)
    return [f"assets={demo['assets']}", f"recon={recon}", f"stage3.iterations={demo['stage3']['iterations']}",
            f"stage2.inference.num_steps={demo['stage2']['inference']['num_steps']}"]


DEMO = demo_overrides()
GSPI_STAGES = ("stage1", "stage2", "stage3", "render")


def preset_overrides(preset: str) -> list[str]:
    """The demo's settings (``small``: its shipped assets), or at ``tiny`` the same but the asset
    reconstructed by recon=tiny (no shipped asset)."""
    if preset == "small":
        return DEMO
    return [o for o in DEMO if not o.startswith(("assets=", "recon="))] + ["recon=tiny"]


def method_meta(data: Path, scene: str, method: str, out: Path, preset: str = "small") -> dict:
    """Runs one method on one scene (the demo's settings); returns its prediction's meta.json."""
    command_seconds("gspi-run", [f"data={data}", f"out={out}", f"method={method}", f"scenes=[{scene}]",
                                 "threads=1", "logger=none", *preset_overrides(preset)], cwd=REPO)  # assets= is relative
    return json.loads((out / "predictions" / scene / "meta.json").read_text())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", choices=("small", "tiny"), default="small", help="the data's preset")
    parser.add_argument("--data", type=Path, default=None, help="a test set of that preset (default: generate it)")
    parser.add_argument("--scene", default=None, help="default: s004_superquadric_metal (small), the first test scene (tiny)")
    args = parser.parse_args()
    print(machine())
    print(f"load average at start: {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory(prefix="bench_pipeline_") as tmp:
        tmp = Path(tmp)
        data = args.data
        if data is None:
            data = tmp / "data"
            command_seconds("gspi-data", [f"preset={args.preset}", f"out={data}", "seed=0", "data.only_splits=[test]",
                                          "data.workers=1"])
        scene = args.scene or ("s004_superquadric_metal" if args.preset == "small"
                               else json.loads((data / "splits.json").read_text())["test"][0])
        gspi = method_meta(data.resolve(), scene, "gspi", tmp / "gspi", args.preset)
        joint = method_meta(data.resolve(), scene, "joint_ir", tmp / "joint_ir", args.preset)
        work = tmp / "gspi" / "work" / scene
        stage1 = json.loads((work / "stage1.json").read_text())["seconds"]
        stage3 = json.loads((work / "stage3.json").read_text())
    stages = {k: gspi["stages"][k]["seconds"] for k in GSPI_STAGES if k in gspi["stages"]}
    g_mat, j_mat = gspi["runtime_s"]["material"], joint["runtime_s"]["material"]
    print(f"\n{scene} ({args.preset}), demo settings, one thread; seconds")
    print(f"  GS-PI   Stage I {stages['stage1']:.1f} (lattice render {stage1['render']:.1f}, filters "
          f"{stage1['filters']:.1f}) | Stage II {stages['stage2']:.1f} | Stage III {stages['stage3']:.1f} "
          f"({1e3 * stage3['seconds_per_iteration']:.1f} ms/iteration x {stage3['iterations']}) | render "
          f"{stages['render']:.1f} | material {g_mat:.1f}")
    print(f"  joint IR material {j_mat:.1f}")
    print(f"  GS-PI / joint IR material time: {g_mat / j_mat:.2f}")
    print(f"load average at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()

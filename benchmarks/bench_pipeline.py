"""Per-stage times of GS-PI on demo-like scenes, and GS-PI vs joint IR material time, in one run.

The demo's settings (conf/experiment/demo.yaml: the shipped ``recon=fast`` asset, the default
Stage II checkpoint at 10 DDIM steps, 100 Stage III iterations), one thread: ``gspi-run`` runs
``method=gspi`` and then ``method=joint_ir`` on the scenes, each method in one fresh process, and the
times come from what the runs recorded (``predictions/<scene>/meta.json``: the StageClock of
each stage; material time = Stage I + II + III + render for GS-PI, the optimisation for joint
IR, as Table 1 counts them). Inside GS-PI's stages: Stage I's render / filters split
(``stage1.json``) and Stage III's seconds per iteration (``stage3.json``).

Data: ``--data`` (a ``small`` test set, e.g. ``demo_out/data`` after ``make demo``); without it
the demo's data are generated into a temp folder first (``gspi-data preset=small seed=0
'data.only_splits=[test]'``, ~1 min).

    python -m benchmarks.bench_pipeline [--data demo_out/data] [--scenes s004_superquadric_metal ...] [--record F]
    python -m benchmarks.bench_pipeline --preset tiny   # the two `tiny` test scenes (64 px), assets made by recon=tiny

``--preset tiny``: the issue's other scale (``gspi-data preset=tiny seed=0``, its two test scenes; Stage I's lattice at their 64 px);
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
    """The demo's settings as gspi-run overrides, read from conf/experiment/demo.yaml (its one definition):
    its asset folder, Stage 0 preset and every stage2 / stage3 key it sets."""
    import yaml

    demo = yaml.safe_load((REPO / "conf" / "experiment" / "demo.yaml").read_text())
    recon = next(d["override /recon"] for d in demo["defaults"] if isinstance(d, dict) and "override /recon" in d)

    def flat(prefix: str, node) -> list[str]:
        if isinstance(node, dict):
            return [o for k, v in node.items() for o in flat(f"{prefix}.{k}", v)]
        return [f"{prefix}={node}"]
    return [f"assets={demo['assets']}", f"recon={recon}", *flat("stage3", demo["stage3"]), *flat("stage2", demo["stage2"])]


DEMO = demo_overrides()
GSPI_STAGES = ("stage1", "stage2", "stage3", "render")


def preset_overrides(preset: str) -> list[str]:
    """The demo's settings (``small``: its shipped assets), or at ``tiny`` the same but the asset
    reconstructed by recon=tiny (no shipped asset) and Stage I's lattice at the scenes' 64 px, as
    the demo's is at its scenes' 128 (gspi-run warns when they differ). On 12 held-out tiny
    scenes the 64-px lattice is also the better read: roughness +4.37 [+0.72, +7.95], metallic
    +1.76 [+0.65, +2.91] dB over the 128-px one at 20 000 points (results/speed/cpu/budget_tiny_heldout_round3.json)."""
    if preset == "small":
        return DEMO
    return [o for o in DEMO if not o.startswith(("assets=", "recon="))] + ["recon=tiny", "stage1.image_size=64"]


def material_cpu(meta: dict, stages: tuple[str, ...]) -> float:
    """CPU seconds of a prediction's material stages (gspi.stage_clock): what they cost on a machine
    shared with other jobs, where the wall time also counts the others' share of the cores."""
    return sum(meta["stages"][s]["cpu_seconds"] for s in stages if s in meta["stages"])


def method_metas(data: Path, scenes: list[str], method: str, out: Path, preset: str = "small") -> list[dict]:
    """Runs one method on ``scenes`` in one process (the demo's settings); returns each
    prediction's meta.json. The first scene also carries the process's one-time costs (lazy
    imports such as torch._dynamo's ~1.5 s on the first optimiser, numba's cached kernels)."""
    command_seconds("gspi-run", [f"data={data}", f"out={out}", f"method={method}", f"scenes=[{','.join(scenes)}]",
                                 "threads=1", "logger=none", *preset_overrides(preset)], cwd=REPO)  # assets= is relative
    return [json.loads((out / "predictions" / scene / "meta.json").read_text()) for scene in scenes]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", choices=("small", "tiny"), default="small", help="the data's preset")
    parser.add_argument("--data", type=Path, default=None, help="a test set of that preset (default: generate it)")
    parser.add_argument("--scenes", nargs="+", default=None,
                        help="default: the test scenes (the demo's 4 at small, 2 at tiny)")
    parser.add_argument("--record", type=Path, default=None,
                        help="also write the figures as JSON here (results/bench/pipeline_<preset>.json: README's "
                             "speed block, `make results`)")
    args = parser.parse_args()
    print(machine())
    load_start = os.getloadavg()[0]
    print(f"load average at start: {load_start:.2f}")
    with tempfile.TemporaryDirectory(prefix="bench_pipeline_") as tmp:
        tmp = Path(tmp)
        data = args.data
        if data is None:
            data = tmp / "data"
            command_seconds("gspi-data", [f"preset={args.preset}", f"out={data}", "seed=0", "data.only_splits=[test]",
                                          "data.workers=1"])
        scenes = args.scenes or json.loads((data / "splits.json").read_text())["test"]
        gspi = method_metas(data.resolve(), scenes, "gspi", tmp / "gspi", args.preset)
        joint = method_metas(data.resolve(), scenes, "joint_ir", tmp / "joint_ir", args.preset)
        works = [tmp / "gspi" / "work" / scene for scene in scenes]
        stage1 = [json.loads((w / "stage1.json").read_text())["seconds"] for w in works]
        stage3 = [json.loads((w / "stage3.json").read_text()) for w in works]
    print(f"\n{args.preset}, demo settings, one thread, each method's scenes in one process "
          "(the first scene carries its one-time imports); seconds")
    for k, scene in enumerate(scenes):
        st = {s: gspi[k]["stages"][s]["seconds"] for s in GSPI_STAGES if s in gspi[k]["stages"]}
        g_mat, j_mat = gspi[k]["runtime_s"]["material"], joint[k]["runtime_s"]["material"]
        print(f"  {scene}\n    GS-PI   Stage I {st['stage1']:.1f} (lattice render {stage1[k]['render']:.1f}, filters "
              f"{stage1[k]['filters']:.1f}) | Stage II {st['stage2']:.1f} | Stage III {st['stage3']:.1f} "
              f"({1e3 * stage3[k]['seconds_per_iteration']:.1f} ms/iteration x {stage3[k]['iterations']}) | render "
              f"{st['render']:.1f} | material {g_mat:.1f}\n    joint IR material {j_mat:.1f}   "
              f"GS-PI / joint IR {g_mat / j_mat:.2f}")
    g_all = sum(m["runtime_s"]["material"] for m in gspi)
    j_all = sum(m["runtime_s"]["material"] for m in joint)
    g_cpu, j_cpu = sum(material_cpu(m, GSPI_STAGES) for m in gspi), sum(material_cpu(m, ("material",)) for m in joint)
    print(f"  all {len(scenes)} scene(s): GS-PI {g_all:.1f} s, joint IR {j_all:.1f} s, GS-PI / joint IR material "
          f"time: {g_all / j_all:.2f} (CPU time {g_cpu:.1f} / {j_cpu:.1f} s: {g_cpu / j_cpu:.2f})")
    print(f"load average at end: {os.getloadavg()[0]:.2f}")
    if args.record:
        record = {"what": "GS-PI vs joint IR material time (benchmarks/bench_pipeline.py)", "preset": args.preset,
                  "settings": preset_overrides(args.preset), "machine": machine(),
                  "load_average": [round(load_start, 2), round(os.getloadavg()[0], 2)],
                  "command": f"python -m benchmarks.bench_pipeline --preset {args.preset} --record {args.record}",
                  "scenes": {scene: {"gspi_material_s": gspi[k]["runtime_s"]["material"],
                                     "joint_ir_material_s": joint[k]["runtime_s"]["material"],
                                     "gspi_stages_s": {s: gspi[k]["stages"][s]["seconds"] for s in GSPI_STAGES
                                                       if s in gspi[k]["stages"]}}
                             for k, scene in enumerate(scenes)},
                  "gspi_material_s": round(g_all, 2), "joint_ir_material_s": round(j_all, 2),
                  "ratio": round(g_all / j_all, 3),
                  "gspi_material_cpu_s": round(g_cpu, 2), "joint_ir_material_cpu_s": round(j_cpu, 2),
                  "ratio_cpu": round(g_cpu / j_cpu, 3)}
        args.record.parent.mkdir(parents=True, exist_ok=True)
        args.record.write_text(json.dumps(record, indent=1) + "\n")
        print(f"wrote {args.record}")


if __name__ == "__main__":
    main()

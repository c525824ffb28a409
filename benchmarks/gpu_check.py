"""One-shot GPU check of GS-PI (issue #16): one command, one output folder, one time budget.

    python -m benchmarks.gpu_check --out OUT                 # on a CUDA machine (8 min budget)
    python -m benchmarks.gpu_check --out OUT --smoke         # the same steps at tiny size, CPU

Steps, in order (each records its numbers or why it was skipped; the JSON is rewritten after
every step, so a killed run keeps what finished):

1. ``gpu_tests``: ``pytest -m gpu`` (gsplat vs the torch rasterizer, images and gradients).
2. ``e2e_tiny``: a tiny end-to-end gspi-run on CUDA and on the CPU; metrics within ``E2E_RTOL``.
3. ``stage2_train_throughput``: training points/s of the Stage II model (``stage2=default``).
4. ``stage2_sampling_linearity``: whole-cloud DDIM sampling time at N and 10N; t(10N)/t(N).
5. ``paper_scene``: one scene at 512 px, 32 views, whole cloud, 50 DDIM steps, 500 Stage III
   iterations, ``stage2=default`` (untrained: 2 steps), ``recon=default``: wall time and peak GPU
   memory of every stage (meta.json).
6. ``data_eval_cuda``: gspi-data on the CPU and with ``device=cuda`` (same seed): time, mask
   agreement and map differences; then gspi-eval of the CUDA dataset against the CPU one with
   ``device=cpu`` and ``device=cuda``: the scores within ``E2E_RTOL`` (the ``device=`` of
   gspi-data and gspi-eval, issue #16; gspi-run's eval on CUDA is also in step 2).
7. ``stage2_train_burst``: Stage II training on the data generated in step 2 with the time
   left; saves the checkpoint (EMA-only into OUT when small enough, else its size and hash).

A step starts only when the budget left covers its estimate; else it is recorded as skipped.
Writes OUT/gpu_check.json, OUT/gpu_check.log (and the checkpoint). docs/REPRODUCE.md "GPU check".
"""
from __future__ import annotations

import argparse
import hashlib
import json
import logging
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
log = logging.getLogger("gpu_check")
E2E_RTOL = 0.02  # metrics of the CUDA run within 2 % of the CPU run (other rasterizer: gsplat)
GPU_TEST_FILES = ["tests/test_rasterize.py"]  # the @pytest.mark.gpu tests (gsplat vs torch)
PAPER = {"image_size": 512, "num_views": 32, "ddim_steps": 50, "stage3_iterations": 500,
         "sampling_points": 50_000, "throughput_steps": 10, "train_batch": 8, "budget_s": 480,
         "data_image_size": 64}
SMOKE = {"image_size": 32, "num_views": 32, "ddim_steps": 2, "stage3_iterations": 4,
         "sampling_points": 300, "throughput_steps": 2, "train_batch": 2, "budget_s": 600,
         "data_image_size": 32}
# step -> seconds it needs at least (paper size on one H100/H200, gsplat's compile included)
ESTIMATE_S = {"gpu_tests": 120, "e2e_tiny": 90, "stage2_train_throughput": 30,
              "stage2_sampling_linearity": 40, "paper_scene": 150, "data_eval_cuda": 40,
              "stage2_train_burst": 20}
# data_eval_cuda: one training and one test scene, two test views, one relight environment
DATA_CHECK = ["preset=tiny", "seed=0", "data.num_train_scenes=1", "data.num_val_scenes=0",
              "data.num_test_scenes=1", "data.num_test_views=2", "data.num_val_views=0",
              "data.num_relight_envs=1", "data.contact_sheets=false"]
MAP_FILES = ("mask.png", "albedo.png", "roughness.png", "metallic.png", "normal.exr", "depth.exr", "rgb.exr")
TINY_EXTRA = ["stage2.prior.alexnet.input_size=64"]  # the tests' tiny prior (tests/stage2_fixtures.py)
PAPER_FIGURES = {"material_min_per_scene": 5.4, "stage2_s_50_ddim": 18.0, "end_to_end_min_512px": 10.4}


class Budget:
    def __init__(self, seconds: float):
        self.t0, self.seconds = time.perf_counter(), float(seconds)

    def left(self) -> float:
        return self.seconds - (time.perf_counter() - self.t0)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _peak_reset(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)


def _peak_mb(device: torch.device):
    return round(torch.cuda.max_memory_allocated(device) / 2**20, 1) if device.type == "cuda" else None


def _stage2_model(smoke: bool, device: torch.device):
    """The paper-size Stage II model (``stage2=default``; ``stage2=tiny`` in smoke mode)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from gspi.stage2.config import complete_stage2
    from gspi.stage2.model import RCWDenoiser
    from gspi.stage2.train import rcw_config

    with initialize_config_dir(version_base="1.3", config_dir=str(REPO / "conf")):
        cfg = compose("gspi_train", overrides=["data_dir=.", "out=.", f"stage2={'tiny' if smoke else 'default'}"])
    stage2 = complete_stage2(OmegaConf.to_container(cfg.stage2, resolve=True))
    torch.manual_seed(0)
    return RCWDenoiser(rcw_config(stage2, 256)).to(device), stage2


def _synthetic_inputs(model, num_points: int, batch: int, device: torch.device):
    from gspi.stage2.inputs import Stage2Inputs

    g = torch.Generator().manual_seed(0)
    c = model.config
    xyz = torch.nn.functional.normalize(torch.randn(batch, num_points, 3, generator=g), dim=-1)
    local = torch.rand(batch, num_points, c.local_cond_dim, generator=g)
    tokens = torch.randn(batch, 32, 25, c.global_token_dim, generator=g)
    f0 = torch.rand(batch, num_points, 5, generator=g) * 2 - 1
    return f0.to(device), Stage2Inputs(xyz=xyz, local_cond=local, global_tokens=tokens).to(device)


def step_gpu_tests(ctx: dict) -> dict:
    if ctx["device"].type != "cuda":
        return {"skipped": "no CUDA: the gpu tests skip themselves"}
    cmd = [sys.executable, "-m", "pytest", "-q", "-rs", "-m", "gpu", "-p", "no:cacheprovider", *GPU_TEST_FILES]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True,
                          timeout=max(30, min(240, ctx["budget"].left())))
    (ctx["out"] / "pytest_gpu.txt").write_text(proc.stdout + proc.stderr)
    return {"returncode": proc.returncode, "summary": (proc.stdout.strip().splitlines() or [""])[-1]}


def _tiny_job(ctx: dict, name: str, device: str, extra: list[str] = ()) -> dict:
    """A gspi-run job with every stage at its smallest (tests/run_helpers.py TINY_RUN)."""
    from tests.run_helpers import TINY_RUN

    return _job(ctx, name, [*TINY_RUN, f"device={device}", *TINY_EXTRA, *extra])


def _job(ctx: dict, name: str, overrides: list[str]) -> dict:
    """One gspi-run job in-process (as the CLI composes it) on ``ctx["data"]``; its metrics."""
    from eval.config import register_configs
    from gspi.run.runner import run_job
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    out = ctx["work"] / name
    register_configs()
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base="1.3"):
        cfg = compose("gspi_run", overrides=[f"data_dir={ctx['data']}", f"out={out}", "figures=false",
                                             "logger=none", "progress=false", *overrides])
    cfg = OmegaConf.to_container(cfg, resolve=True)
    t0 = time.perf_counter()
    result = run_job(cfg)
    numbers = {}
    for name, key in (("eval", None), ("points_eval", "mean")):  # material maps; Table 2's points
        summary = out / name / "summary.json"
        if summary.is_file():
            data = json.loads(summary.read_text())
            numbers.update(_leaves(data[key] if key else data, name + "."))
    return {"seconds": round(time.perf_counter() - t0, 2), "status": result.get("status"),
            "error": result.get("error"), "numbers": numbers, "out": str(out)}


def _leaves(obj, prefix: str) -> dict:
    """``{"a.b.c": number}`` of a nested summary."""
    if isinstance(obj, dict):
        found = {}
        for k, v in obj.items():
            found.update(_leaves(v, f"{prefix}{k}."))
        return found
    return {prefix[:-1]: float(obj)} if isinstance(obj, (int, float)) and not isinstance(obj, bool) else {}


def step_e2e_tiny(ctx: dict) -> dict:
    from tests.run_helpers import make_micro_dataset

    t0 = time.perf_counter()
    ctx["data"] = make_micro_dataset(ctx["work"] / "data")
    report = {"data_seconds": round(time.perf_counter() - t0, 2), "cpu": _tiny_job(ctx, "e2e_cpu", "cpu")}
    if ctx["device"].type != "cuda":
        report["cuda"] = {"skipped": "no CUDA"}
        return report
    report["cuda"] = _tiny_job(ctx, "e2e_cuda", "cuda")
    a, b = report["cpu"]["numbers"], report["cuda"]["numbers"]
    diffs = {k: (a[k], b[k]) for k in sorted(set(a) & set(b))
             if not np.isclose(a[k], b[k], rtol=E2E_RTOL, atol=1e-3)}
    report.update(rtol=E2E_RTOL, compared=len(set(a) & set(b)), outside_tolerance=diffs, ok=not diffs)
    return report


def step_stage2_train_throughput(ctx: dict) -> dict:
    from gspi.stage2.loss import denoising_loss

    device, cfg = ctx["device"], ctx["sizes"]
    model, stage2 = _stage2_model(ctx["smoke"], device)
    n, batch = int(stage2.data.num_points), int(cfg["train_batch"])
    f0, inputs = _synthetic_inputs(model, n, batch, device)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-4)
    gen = torch.Generator().manual_seed(0)

    def one_step():
        loss = denoising_loss(model, f0, inputs, generator=gen)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    one_step()  # warm-up (allocator, kernels)
    _sync(device), _peak_reset(device)
    t0 = time.perf_counter()
    for _ in range(int(cfg["throughput_steps"])):
        one_step()
    _sync(device)
    seconds = time.perf_counter() - t0
    steps = int(cfg["throughput_steps"])
    return {"points_per_step": n * batch, "batch": batch, "num_points": n, "steps": steps,
            "seconds": round(seconds, 3), "points_per_s": round(n * batch * steps / seconds, 1),
            "peak_gpu_mb": _peak_mb(device), "parameters": sum(p.numel() for p in model.parameters())}


def step_stage2_sampling_linearity(ctx: dict) -> dict:
    from gspi.stage2.sampler import predict_point_pbr

    device, cfg = ctx["device"], ctx["sizes"]
    model, _ = _stage2_model(ctx["smoke"], device)
    model.eval()
    report = {"ddim_steps": int(cfg["ddim_steps"])}
    for label, n in (("N", int(cfg["sampling_points"])), ("10N", 10 * int(cfg["sampling_points"]))):
        rng = np.random.default_rng(0)
        xyz = rng.normal(size=(n, 3))
        cond = rng.uniform(size=(n, model.config.local_cond_dim)).astype(np.float32)
        feats = torch.randn(32, model.config.global_token_dim, 5, 5)
        if label == "N":  # warm-up at the small size
            predict_point_pbr(model, xyz[:1000], cond[:1000], feats, num_steps=1, device=device)
        _sync(device), _peak_reset(device)
        t0 = time.perf_counter()
        predict_point_pbr(model, xyz, cond, feats, num_steps=int(cfg["ddim_steps"]), device=device)
        _sync(device)
        report[label] = {"points": n, "seconds": round(time.perf_counter() - t0, 3), "peak_gpu_mb": _peak_mb(device)}
    report["ratio_10N_over_N"] = round(report["10N"]["seconds"] / report["N"]["seconds"], 2)
    return report


def step_paper_scene(ctx: dict) -> dict:
    """One scene at paper size through gspi-run (untrained paper-size Stage II: the timings do
    not depend on the weights; stage2.train.steps=2 gives the run a checkpoint)."""
    if "data" not in ctx:
        return {"skipped": "no data (e2e_tiny did not run)"}
    from eval.common.argv import apply_aliases
    from gspi.cli.data import run as data_run
    from hydra import compose, initialize_config_dir

    cfg = ctx["sizes"]
    size = int(cfg["image_size"])
    data, t0 = ctx["data"], time.perf_counter()
    if not ctx["smoke"]:  # one 512 px scene (+ one training scene for Stage II's 2 steps)
        data = ctx["work"] / "paper_data"
        overrides = ["preset=tiny", f"out={data}", "seed=0", "data.workers=8", "data.num_train_scenes=1",
                     "data.num_val_scenes=0",
                     "data.num_test_scenes=1", f"data.image_size={size}", "data.supersample=1",
                     "data.num_test_views=2", "data.num_val_views=1", "data.num_relight_envs=1",
                     "data.contact_sheets=false"]
        with initialize_config_dir(config_dir=str(REPO / "conf"), version_base="1.3"):
            data_run(compose("gspi_data", overrides=apply_aliases(overrides, "gspi_data")))
    data_s = time.perf_counter() - t0
    device = "cuda" if ctx["device"].type == "cuda" else "cpu"
    stage2 = "stage2=tiny" if ctx["smoke"] else "stage2=default"
    ctx_saved = ctx["data"]
    ctx["data"] = data
    try:
        scale = (["recon=tiny", "recon.iterations=60", "recon.init.num_points=300", *TINY_EXTRA]
                 if ctx["smoke"] else ["recon=default"])  # the paper's 2DGS asset (1500 iterations)
        job = _job(ctx, "paper_scene", [
            f"device={device}", *scale, stage2, "stage2.train.steps=2", "stage2.inference.max_points=null",
            f"stage2.inference.num_steps={int(cfg['ddim_steps'])}", "stage1=default", f"stage1.image_size={size}",
            f"stage1.num_views={int(cfg['num_views'])}", "stage3=default",
            f"stage3.iterations={int(cfg['stage3_iterations'])}"])
    finally:
        ctx["data"] = ctx_saved
    metas = list(Path(job["out"]).glob("predictions/*/meta.json"))
    meta = json.loads(metas[0].read_text()) if metas else {}
    runtime = meta.get("runtime_s", {})
    return {"data_seconds": round(data_s, 2), "image_size": size, "job_seconds": job["seconds"],
            "status": job["status"], "error": job["error"], "stages": meta.get("stages"),
            "material_s": runtime.get("material"), "end_to_end_s": runtime.get("end_to_end"),
            "paper": PAPER_FIGURES}


def step_stage2_train_burst(ctx: dict) -> dict:
    if "data" not in ctx:
        return {"skipped": "no data (e2e_tiny did not run)"}
    from gspi.stage2.checkpoint import export_ema_only
    from gspi.stage2.distributed import DistContext
    from gspi.stage2.train import train
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    steps = 3 if ctx["smoke"] else max(1, int((ctx["budget"].left() - 15) / 0.5))  # ~0.5 s/step bound
    run_dir = ctx["work"] / "stage2_burst"
    overrides = [f"data_dir={ctx['data']}", f"out={run_dir}", f"stage2={'tiny' if ctx['smoke'] else 'default'}",
                 f"stage2.train.steps={steps}", f"stage2.train.checkpoint_every={max(1, steps)}",
                 f"stage2.train.batch_size={int(ctx['sizes']['train_batch'])}"]
    with initialize_config_dir(version_base="1.3", config_dir=str(REPO / "conf")):
        cfg = OmegaConf.to_container(compose("gspi_train", overrides=overrides), resolve=True)
    stats = train(cfg, run_dir, dist=DistContext(device=ctx["device"]))
    ema = export_ema_only(run_dir / "checkpoint.pt", ctx["work"] / "stage2_burst_ema.pt", half=True)
    size_mb = ema.stat().st_size / 2**20
    digest = hashlib.sha256(ema.read_bytes()).hexdigest()
    kept = None
    if size_mb <= ctx["max_file_mb"]:
        kept = ctx["out"] / "stage2_burst_ema.pt"
        kept.write_bytes(ema.read_bytes())
    return {"steps": stats["steps"], "wall_time_s": stats["wall_time_s"], "final_loss": stats["final_loss"],
            "ema_fp16_mb": round(size_mb, 2), "sha256": digest, "saved": str(kept) if kept else
            f"not copied (> {ctx['max_file_mb']} MB): {ema}"}


def _gspi_data(ctx: dict, name: str, device: str) -> dict:
    """gspi-data (in-process, as the CLI composes it) of the DATA_CHECK dataset on ``device``."""
    from eval.common.argv import apply_aliases
    from gspi.cli.data import run as data_run
    from hydra import compose, initialize_config_dir

    out = ctx["work"] / name
    overrides = [*DATA_CHECK, f"out={out}", f"device={device}", f"data.image_size={int(ctx['sizes']['data_image_size'])}"]
    t0 = time.perf_counter()
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base="1.3"):
        data_run(compose("gspi_data", overrides=apply_aliases(overrides, "gspi_data")))
    _sync(torch.device(device))
    return {"out": out, "seconds": round(time.perf_counter() - t0, 2)}


def _dataset_files(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file() and ".hydra" not in p.parts)


def _dataset_difference(a: Path, b: Path) -> dict:
    """Two datasets of the same config: same files? per map file the largest and the mean
    absolute difference over every view; the fraction of mask pixels that agree."""
    from eval.common.layout import read_scene, read_splits, read_view_file

    diffs = {f: [] for f in MAP_FILES}
    for name in sorted(n for names in read_splits(a).values() for n in names):
        scene = read_scene(a / name)
        for split, views in scene.views.items():
            for v in views:
                for f in MAP_FILES:
                    x, y = (read_view_file(root / name / split / v.id, f) for root in (a, b))
                    diffs[f].append(np.abs(x.astype(np.float64) - y))
    report = {"same_files": _dataset_files(a) == _dataset_files(b),
              "mask_agreement": float(np.mean(np.concatenate([d.ravel() for d in diffs["mask.png"]]) == 0))}
    for f, ds in diffs.items():
        flat = np.concatenate([d.ravel() for d in ds])
        report[f] = {"max_abs": float(flat.max()), "mean_abs": float(flat.mean())}
    return report


def _eval_numbers(gt: Path, pred: Path, device: str) -> dict:
    """gspi-eval's summary of ``pred`` against ``gt`` (default protocol) on ``device``, as leaves."""
    from eval.config import ProtocolConfig
    from eval.evaluate import evaluate
    from omegaconf import OmegaConf

    result = evaluate(gt, pred, OmegaConf.structured(ProtocolConfig), device=torch.device(device))
    return _leaves(result.summary, "")


def step_data_eval_cuda(ctx: dict) -> dict:
    cpu = _gspi_data(ctx, "data_cpu", "cpu")
    report = {"image_size": int(ctx["sizes"]["data_image_size"]), "data_cpu_seconds": cpu["seconds"]}
    if ctx["device"].type != "cuda":
        t0 = time.perf_counter()
        report["eval_cpu"] = _eval_numbers(cpu["out"], cpu["out"], "cpu")  # the oracle, on the CPU
        report.update(eval_cpu_seconds=round(time.perf_counter() - t0, 2), cuda={"skipped": "no CUDA"})
        return report
    cuda = _gspi_data(ctx, "data_cuda", "cuda")
    report.update(data_cuda_seconds=cuda["seconds"], data_difference=_dataset_difference(cpu["out"], cuda["out"]))
    for device in ("cpu", "cuda"):
        t0 = time.perf_counter()
        report[f"eval_{device}"] = _eval_numbers(cpu["out"], cuda["out"], device)  # CUDA data scored against CPU GT
        _sync(torch.device(device))
        report[f"eval_{device}_seconds"] = round(time.perf_counter() - t0, 2)
    a, b = report["eval_cpu"], report["eval_cuda"]
    diffs = {k: (a[k], b[k]) for k in sorted(set(a) & set(b))
             if not np.isclose(a[k], b[k], rtol=E2E_RTOL, atol=1e-3)}
    report.update(rtol=E2E_RTOL, compared=len(set(a) & set(b)), outside_tolerance=diffs, ok=not diffs)
    return report


STEPS: list[tuple[str, Callable[[dict], dict]]] = [
    ("gpu_tests", step_gpu_tests), ("e2e_tiny", step_e2e_tiny),
    ("stage2_train_throughput", step_stage2_train_throughput),
    ("stage2_sampling_linearity", step_stage2_sampling_linearity), ("paper_scene", step_paper_scene),
    ("data_eval_cuda", step_data_eval_cuda), ("stage2_train_burst", step_stage2_train_burst)]


def environment(device: torch.device) -> dict:
    env = {"python": platform.python_version(), "torch": torch.__version__, "cuda": torch.version.cuda,
           "device": str(device), "machine": platform.machine()}
    if device.type == "cuda":
        env["gpu"] = torch.cuda.get_device_name(device)
    try:
        import gsplat
        env["gsplat"] = gsplat.__version__
    except ImportError:
        env["gsplat"] = None
    return env


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, type=Path, help="output folder (JSON, log, checkpoint)")
    parser.add_argument("--smoke", action="store_true", help="the same steps at tiny size on the CPU")
    parser.add_argument("--budget-s", type=float, default=None, help="global time budget (default 480 s)")
    parser.add_argument("--work", type=Path, default=None, help="scratch folder (default OUT/../gpu_check_work)")
    parser.add_argument("--only", default=None, help="comma-separated steps to run (default: all)")
    parser.add_argument("--max-file-mb", type=float, default=15.0, help="largest checkpoint copied into OUT")
    args = parser.parse_args(argv)
    from gspi.device import resolve_device

    device = torch.device("cpu") if args.smoke else resolve_device("cuda", key="gpu_check (needs CUDA; use --smoke)")
    sizes = SMOKE if args.smoke else PAPER
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    work = args.work or out.parent / (out.name + "_work")
    work.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(out / "gpu_check.log", mode="w")
    handler.setFormatter(logging.Formatter("[%(asctime)s][%(name)s][%(levelname)s] %(message)s"))
    logging.getLogger().addHandler(handler)
    logging.getLogger().setLevel(logging.INFO)
    budget = Budget(args.budget_s if args.budget_s is not None else sizes["budget_s"])
    only = set(args.only.split(",")) if args.only else None
    ctx = {"device": device, "smoke": args.smoke, "sizes": sizes, "out": out, "work": work, "budget": budget,
           "max_file_mb": args.max_file_mb}
    report = {"mode": "smoke" if args.smoke else "gpu", "sizes": sizes, "budget_s": budget.seconds,
              "environment": environment(device), "steps": {}, "skipped": []}
    path = out / "gpu_check.json"
    for name, fn in STEPS:
        if only is not None and name not in only:
            continue
        need = 0.0 if args.smoke else ESTIMATE_S[name]
        if budget.left() < need:
            report["skipped"].append({"step": name, "why": f"budget: {budget.left():.0f} s left < {need} s needed"})
            log.warning("%s skipped: budget", name)
            continue
        log.info("%s: start (%.0f s left)", name, budget.left())
        t0 = time.perf_counter()
        try:
            result = fn(ctx)
        except Exception as exc:  # a failed step is recorded; the others still run
            log.exception("%s failed", name)
            result = {"error": f"{type(exc).__name__}: {exc}"}
        result["step_seconds"] = round(time.perf_counter() - t0, 2)
        report["steps"][name] = result
        path.write_text(json.dumps(report, indent=2, default=str))
        log.info("%s: done in %.1f s", name, result["step_seconds"])
    report["total_seconds"] = round(budget.seconds - budget.left(), 2)
    path.write_text(json.dumps(report, indent=2, default=str))
    logging.getLogger().removeHandler(handler)
    handler.close()
    print(json.dumps({k: report[k] for k in ("mode", "total_seconds", "skipped")}, default=str))
    return report


if __name__ == "__main__":
    main()

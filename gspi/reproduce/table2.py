"""Table 2 at a named scale as steps (``gspi.reproduce.plan``): training pool -> held-out pool ->
Stage 0 reconstructions of both -> one Stage II training per (variant, seed), in chunks ->
Table 2's measure on the held-out scenes (gspi-points-eval), its scores committed -> the table (gspi-table).

Config: conf/reproduce/table2_<scale>.yaml (its comments name every key). A (variant, seed)
whose scores are committed (``scores_dir``, or a file ``scores_from`` names) needs nothing
else; one whose checkpoint is committed (``checkpoints_from``) is measured, not trained; the data
steps run only while some run still needs them.
"""
from __future__ import annotations

import json
import sys
from functools import cache, partial
from pathlib import Path
from typing import Any, Callable, Mapping

from gspi.reproduce.costs import cost, scene_count
from gspi.reproduce.plan import Step
from eval.common.errors import MissingInputError
from gspi.reproduce.kept_state import restore
from eval.portable import write_portable_scores

BIN = Path(sys.executable).parent


def tool(name: str) -> str:
    """A gspi console script of this environment (the one running gspi-reproduce)."""
    return str(BIN / name)


def python_module(module: str) -> list[str]:
    return [sys.executable, "-m", module]


def runs_folder(cfg: Mapping[str, Any]) -> str:
    """The work folder's subfolder of this table's run folders (one per Stage 0 conditions)."""
    return cfg.get("runs") or f"runs_{cfg['recon']}"


def run_name(variant: str, seed: int) -> str:
    return f"{variant}_s{seed}"


def training_done(run_dir: Path) -> bool:
    """gspi-train wrote stats.json with every step of the recipe taken."""
    stats = run_dir / "stats.json"
    if not stats.is_file():
        return False
    s = json.loads(stats.read_text())
    return int(s.get("steps", 0)) >= int(s.get("total_steps", 1 << 30))


def pool_steps(cfg: Mapping[str, Any], work: Path) -> list[Step]:
    """Generate both pools, their dataset views and their Stage 0 reconstructions."""
    done = work / ".done"
    recon = cfg["recon"]
    tp, hp = cfg["train_pool"], cfg["heldout_pool"]
    train_range = ":".join(map(str, tp["indices"][0]))
    data = lambda out, indices, keys: [  # noqa: E731
        tool("gspi-data"), "preset=stage2_pool", f"out={out}", "seed=0",
        f"data.pool_indices={json.dumps(indices).replace(' ', '')}", f"data.workers={cfg['workers']}", *keys]
    split = lambda pool, view, *ranges: [*python_module("gspi.data.pool.split"), str(pool), str(view), *ranges]  # noqa: E731
    reconstruct = lambda src, out: [*python_module("gspi.recon.reconstructed_pool"), str(src), str(out),  # noqa: E731
                                    *cfg["recon_overrides"], "--recon", recon, "--workers", str(cfg["workers"])]
    recorded = cfg["measure"].get("baseline")  # the constants from committed scores: no pool scenes for them
    heldout_indices = [list(hp["test"])] if recorded else [list(hp["train"]), list(hp["test"])]
    scale = cfg["scale"]
    estimate = lambda kind, count=1: (lambda: cost(scale, kind, count))  # noqa: E731
    n_train, n_heldout = scene_count(tp["indices"]), scene_count(heldout_indices)
    n_test = scene_count([hp["test"]])
    steps = [
        Step("data: training pool", done / "train_pool", data(work / "train_pool", list(map(list, tp["indices"])),
                                                                tp["keys"]), cpu_s_left=estimate("data: pool", n_train)),
        Step("data: training view", done / "train_view", split(work / "train_pool", work / "train_view",
                                                                 "--train", train_range), cpu_s_left=estimate("data: view")),
        Step("data: held-out pool", done / "heldout_pool", data(work / "heldout_pool", heldout_indices, hp["keys"]),
             cpu_s_left=estimate("data: pool", n_heldout)),
        Step("data: held-out views", done / "heldout_views",
             split(work / "heldout_pool", work / "heldout_test", "--test", ":".join(map(str, hp["test"]))),
             cpu_s_left=estimate("data: view")),
        *([] if recorded else [Step("data: baseline view", done / "baseline_view",
                                    split(work / "heldout_pool", work / "baseline_train", "--train",
                                          ":".join(map(str, hp["train"]))), cpu_s_left=estimate("data: view"))]),
        Step(f"stage 0: training pool (recon={recon})", done / f"recon_train_{recon}",
             reconstruct(work / "train_view", work / f"rtrain_{recon}"), cpu_s_left=estimate("stage 0", n_train)),
        Step(f"stage 0: held-out scenes (recon={recon})", done / f"recon_heldout_{recon}",
             reconstruct(work / "heldout_test", work / f"rheldout_{recon}"), cpu_s_left=estimate("stage 0", n_test)),
    ]
    if reads_asset_stage1(cfg):  # the light read as a run reads it: Stage I of every asset, kept beside it
        stage1 = lambda pool: [*python_module("gspi.stage1.pool_clouds"), str(pool)]  # noqa: E731
        steps += [Step("stage 1: training pool's assets", done / f"stage1_train_{recon}",
                       stage1(work / f"rtrain_{recon}"), cpu_s_left=estimate("stage 1", n_train)),
                  Step("stage 1: held-out assets", done / f"stage1_heldout_{recon}",
                       stage1(work / f"rheldout_{recon}"), cpu_s_left=estimate("stage 1", n_test))]
    return steps


def reads_asset_stage1(cfg: Mapping[str, Any]) -> bool:
    """Whether a planned variant reads Stage II's light condition on Stage I of the pool's assets
    (``stage2.data.light_geometry=asset`` among its ``variant_overrides``)."""
    return any(str(o).replace(" ", "") == "stage2.data.light_geometry=asset"
               for variant, overrides in (cfg.get("variant_overrides") or {}).items()
               if variant in cfg["variants"] for o in overrides)


def saved_step(run_dir: Path) -> tuple[int, int] | str | None:
    """(step, of steps) of a run's last checkpoint; None before its first; a string saying why a
    checkpoint could not be read (a plan line must not fail on a half-written or foreign file)."""
    import torch

    ckpt = run_dir / "checkpoint.pt"
    if not ckpt.is_file():
        return None
    try:  # mmap: the step and config only, not the optimizer's tensors
        saved = torch.load(ckpt, map_location="cpu", weights_only=True, mmap=True)
        return int(saved["step"]), int(saved["config"]["stage2"]["train"]["steps"])
    except Exception as exc:
        return f"checkpoint unreadable: {type(exc).__name__}"


def training_progress(saved: tuple[int, int] | str | None) -> str | None:
    """``at step k of n`` from :func:`saved_step` (None before the run's first checkpoint)."""
    return f"at step {saved[0]} of {saved[1]}" if isinstance(saved, tuple) else saved


def steps_taken(saved: tuple[int, int] | str | None) -> int:
    """The steps :func:`saved_step` says a run has taken (0 before its first checkpoint)."""
    return saved[0] if isinstance(saved, tuple) else 0


def recipe_train(root: Path, stage2: str) -> dict:
    """The ``train`` node of a flat recipe file (conf/stage2/<name>.yaml; {} when it has none)."""
    import yaml

    path = root / "conf" / "stage2" / f"{stage2}.yaml"
    return (yaml.safe_load(path.read_text()) or {}).get("train") or {} if path.is_file() else {}


def rates_and_steps(root: Path, stage2: str, runs: str) -> tuple[dict[str, float], int | None]:
    """({variant: CPU-s per step} from the recipe's run log, the recipe's steps): what a training's
    estimate needs, read once per plan (``table2_steps`` caches it) and only when asked."""
    recipe = recipe_train(root, stage2)
    rates = cpu_seconds_per_step(root / recipe["run_log"], runs) if recipe.get("run_log") else {}
    return rates, int(recipe["steps"]) if recipe.get("steps") else None


def cpu_seconds_per_step(run_log: Path, runs: str) -> dict[str, float]:
    """Each variant's CPU-seconds per training step over the chunks of ``runs`` (a runs folder,
    e.g. ``runs_fast``) that gspi-train appended to the committed run log, all seeds together."""
    cpu: dict[str, float] = {}
    steps: dict[str, int] = {}
    lines = run_log.read_text().splitlines() if run_log.is_file() else []
    for line in filter(None, map(str.strip, lines)):
        chunk = json.loads(line)
        parts = Path(str(chunk.get("out", ""))).parts
        if len(parts) < 2 or parts[-2] != runs or "_s" not in parts[-1]:
            continue
        variant = parts[-1].rsplit("_s", 1)[0]
        first, last = chunk["steps"]
        if last > first and chunk.get("cpu_s_this_run"):
            cpu[variant] = cpu.get(variant, 0.0) + float(chunk["cpu_s_this_run"])
            steps[variant] = steps.get(variant, 0) + last - first
    return {v: cpu[v] / steps[v] for v in cpu}


def run_steps(cfg: Mapping[str, Any], work: Path, variant: str, seed: int, scores: Path, root: Path,
              rates: Callable[[], tuple[dict[str, float], int | None]]) -> list[Step]:
    """Train one (variant, seed) in chunks, then measure it and commit its scores; ``rates``: the
    plan's cached :func:`rates_and_steps`."""
    recon = cfg["recon"]
    name = run_name(variant, seed)
    runs = runs_folder(cfg)
    run_dir = work / runs / name  # a work folder holds runs of several conditions
    train = [tool("gspi-train"), f"data={work / f'rtrain_{recon}'}", f"out={run_dir}", f"stage2={cfg['stage2']}",
             f"ablation={variant}", f"seed={seed}", f"stage2.train.stop_after_minutes={cfg['chunk_minutes']}",
             *cfg["train_overrides"], *(cfg.get("variant_overrides") or {}).get(variant, [])]
    saved = cache(partial(saved_step, run_dir))  # read once per plan: by the progress line and the estimate
    kept = kept_run(cfg, root, runs, name)
    restore_first = [] if kept is None else [  # a run begun elsewhere: its committed state (kept_state.py)
        Step(f"restore: {name}", run_dir / "checkpoint.pt", action=partial(restore, kept, run_dir), marker=False,
             lane_group=name, cpu_s_left=partial(cost, cfg["scale"], "restore"))]

    def cpu_s_left() -> float | None:  # the run log's rate for this variant x the steps it has left
        per_variant, steps = rates()
        # a variant the run log has not seen yet (e.g. light_full) at Full's rate, its nearest recipe
        rate = per_variant.get(variant, per_variant.get("full"))
        if rate is None or steps is None:  # a recipe with no run log (smoke): the scale's per-training rate
            return cost(cfg["scale"], "training")
        return rate * (steps - steps_taken(saved()))

    return restore_first + [
        Step(f"train: {name}", work / ".done" / runs / f"train_{name}", train,  # one marker per runs folder
             repeat_until=lambda: training_done(run_dir), env={"OMP_NUM_THREADS": "1"}, lane_group=name,
             progress=lambda: training_progress(saved()), cpu_s_left=cpu_s_left),
        measure_step(cfg, work, name, run_dir / "checkpoint.pt", run_dir / "eval", scores, root),
    ]


def kept_run(cfg: Mapping[str, Any], root: Path, runs: str, name: str) -> Path | None:
    """The committed training state of run ``name`` (``kept_state``), None when none is kept."""
    kept = cfg.get("kept_state") and root / cfg["kept_state"] / runs / name
    return kept if kept and (kept / "checkpoint.pt").is_file() else None


def keep_training_state(cfg: Mapping[str, Any], *, root: Path) -> list[str]:
    """``keep_state=true``: the state of every planned run not measured yet copied to
    ``kept_state`` (to commit), the copies of measured runs removed; one line per change."""
    assert cfg.get("kept_state"), "the caller checks that the table keeps state"
    from gspi.reproduce.kept_state import keep_state

    work, runs = (root / cfg["work"]).resolve(), runs_folder(cfg)
    names = [run_name(variant, seed) for variant, seed in run_order(cfg)]
    measured = {n for n in names if (root / cfg["scores_dir"] / n / "scores.json").is_file()}
    return keep_state({n: work / runs / n for n in names}, measured, root / cfg["kept_state"])


def measure_overrides(m: Mapping[str, Any]) -> list[str]:
    """The reproduce file's ``measure:`` block as gspi-points-eval overrides: the measure it names
    (``protocol``: conf/points_measure/<name>, default ``table2``) and each of its keys that is a
    knob of the measure (``eval.points_protocol.MEASURE_DEFAULTS``) as an override of that measure."""
    from eval.points_protocol import MEASURE_DEFAULTS

    knobs = [f"points_measure.{k}={'null' if m[k] is None else m[k]}" for k in MEASURE_DEFAULTS if k in m]
    return [f"points_measure={m.get('protocol') or 'table2'}", *knobs]


def measure_step(cfg: Mapping[str, Any], work: Path, name: str, checkpoint: Path, eval_dir: Path, scores: Path,
                 root: Path) -> Step:
    """Table 2's measure of ``checkpoint`` on the held-out scenes (gspi-points-eval, the measure
    named in ``measure``); its scores committed (portable)."""
    m = cfg["measure"]
    baseline = root / m["baseline"] if m.get("baseline") else work / "baseline_train"
    heldout = work / f"rheldout_{cfg['recon']}"
    measure = [tool("gspi-points-eval"), f"checkpoint={checkpoint}", f"data={heldout}", f"out={eval_dir}",
               f"baseline={baseline}", *measure_overrides(m)]
    commit = lambda: write_portable_scores(eval_dir / "scores.json", scores,  # noqa: E731
                                           data_label=m["data_label"], roots={"<work>": work, "<repo>": root})
    n_scenes = scene_count([cfg["heldout_pool"]["test"]])
    return Step(f"measure: {name}", scores, measure, after=commit, env={"OMP_NUM_THREADS": "1"}, lane_group=name,
                marker=False, cpu_s_left=partial(cost, cfg["scale"], "measure", n_scenes))


def checkpoint_steps(cfg: Mapping[str, Any], work: Path, name: str, checkpoint: Path, scores: Path,
                     root: Path) -> list[Step]:
    """A committed checkpoint that stands for its run (``checkpoints_from``, e.g. the shipped model
    as Full seed 0): measured on this work folder's held-out scenes, never trained."""
    if not checkpoint.is_file():
        raise MissingInputError(f"checkpoints_from.{name}: {checkpoint} does not exist")
    runs = runs_folder(cfg)
    return [measure_step(cfg, work, name, checkpoint, work / runs / name / "eval", scores, root)]


def table_step(cfg: Mapping[str, Any], scores_dir: Path, tables_dir: Path) -> Step:
    """gspi-table over the committed scores: Table 2 (md, tex, csv), Δ vs Full with bootstrap CIs."""
    return Step("table", tables_dir / ".built", [tool("gspi-table"), str(scores_dir), f"out={tables_dir}",
                                                 "table=table2"], rebuild=True,
                cpu_s_left=partial(cost, cfg["scale"], "table"))


def run_order(cfg: Mapping[str, Any]) -> list[tuple[str, int]]:
    """The planned (variant, seed) runs in the order they train: seed by seed, variants in config
    order, but the runs ``run_last`` names (variant -> seeds; e.g. A4's seeds 1 and 2, which
    Table 2 may go without) after every other, so the runs a table needs come first; a run it
    names that is not planned (a scale whose ``variants`` or ``seeds`` lack it) is ignored.
    ``variant_seeds`` (variant -> seeds) plans a variant at those of ``seeds`` only."""
    last = {(variant, int(seed)) for variant, seeds in (cfg.get("run_last") or {}).items() for seed in seeds}
    only = {v: {int(s) for s in seeds} for v, seeds in (cfg.get("variant_seeds") or {}).items()}
    runs = [(variant, seed) for seed in cfg["seeds"] for variant in cfg["variants"]
            if variant not in only or int(seed) in only[variant]]
    return [r for r in runs if r not in last] + [r for r in runs if r in last]


def table2_steps(cfg: Mapping[str, Any], *, root: Path) -> list[Step]:
    """Every step of Table 2 at ``cfg``'s scale; ``root``: the repository (committed paths)."""
    work = (root / cfg["work"]).resolve()
    scores_dir, tables_dir = root / cfg["scores_dir"], root / cfg["tables_dir"]
    adopted = adopt_steps(cfg, root, scores_dir)
    shipped = cfg.get("checkpoints_from") or {}
    # the run log of this runs folder, or of the one ``rates_from`` names (the same recipe trained elsewhere)
    rates = cache(partial(rates_and_steps, root, cfg["stage2"], cfg.get("rates_from") or runs_folder(cfg)))
    runs = []
    for variant, seed in run_order(cfg):
        name = run_name(variant, seed)
        scores = scores_dir / name / "scores.json"
        if scores.is_file() or name in adopted:
            continue
        runs += (checkpoint_steps(cfg, work, name, root / shipped[name], scores, root) if name in shipped
                 else run_steps(cfg, work, variant, seed, scores, root, rates))
    steps = list(adopted.values()) + (pool_steps(cfg, work) if runs else []) + runs
    table = table_step(cfg, scores_dir, tables_dir)
    for step in steps:
        step.aliases = {str(work): "<work>"}
    return steps + [table]


def adopt_steps(cfg: Mapping[str, Any], root: Path, scores_dir: Path) -> dict[str, Step]:
    """Scores committed before this command existed (``scores_from``) take their run's place: one
    in-process step per planned run not yet in ``scores_dir`` copies them there (portable); a dry run
    lists these steps and writes nothing."""
    steps = {}
    planned = {run_name(variant, seed) for variant in cfg["variants"] for seed in cfg["seeds"]}
    for key, path in (cfg.get("scores_from") or {}).items():
        variant, seed = key.rsplit("_s", 1)
        name = run_name(variant, int(seed))
        dst = scores_dir / name / "scores.json"
        if name in planned and not dst.is_file():
            steps[name] = Step(f"adopt: {name}", dst, marker=False, action=partial(
                write_portable_scores, root / path, dst, data_label=cfg["measure"]["data_label"], roots={}),
                cpu_s_left=partial(cost, cfg["scale"], "adopt"))
    return steps

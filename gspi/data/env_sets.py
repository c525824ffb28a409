"""Which environments light a dataset: `data.capture_envs` and `data.relight_envs`.

Each option is one of
* `procedural` (default): `gspi.data.environments` CAPTURE_ENVS / HELDOUT_ENVS;
* `polyhaven`: `gspi.data.hdri` POLYHAVEN_CAPTURE / POLYHAVEN_HELDOUT (named `ph_<name>`);
* a list whose entries are environment names (procedural or `ph_<name>`) or paths of a
  user's own lat-long EXR files (named after the file stem).
The two sets must be disjoint: a relighting environment is never seen in the inputs.

A set left at `procedural` keeps the environments `gspi.data.procedural.scene_recipe` drew (datasets
stay byte-identical); another set is redrawn by `assign_environments` from its own seeded
stream, so shape, material, views and jitter of every scene do not change with the sets, and
changing only `relight_envs` leaves the input images byte-identical.
"""
from __future__ import annotations

from pathlib import Path

import torch

from gspi.data.environments import CAPTURE_ENVS, HELDOUT_ENVS, env_names, make_environment
from gspi.data.hdri import POLYHAVEN_CAPTURE, POLYHAVEN_HELDOUT, POLYHAVEN_PREFIX, load_hdri, \
    polyhaven_path
from gspi.data.procedural.scene_recipe import scene_rng

PROCEDURAL = "procedural"
RELIGHT_STREAM, CAPTURE_STREAM = 3, 4  # scene_rng streams of redrawn environments


def resolve_env_set(spec, kind: str) -> dict[str, str]:
    """Config value -> {env name: source}; source is "procedural" or a file path.

    Args:
        spec: "procedural", "polyhaven" or a list of names / EXR paths.
        kind: "capture" or "heldout" (which named set the keywords mean).
    """
    if spec is None or spec == PROCEDURAL:
        return {n: PROCEDURAL for n in env_names(kind)}
    if spec == "polyhaven":
        names = POLYHAVEN_CAPTURE if kind == "capture" else POLYHAVEN_HELDOUT
        return {POLYHAVEN_PREFIX + n: str(polyhaven_path(n)) for n in names}
    if isinstance(spec, str):
        raise ValueError(f"environment set {spec!r}: expected 'procedural', 'polyhaven' or a "
                         "list of environment names / EXR paths")
    out: dict[str, str] = {}
    for entry in spec:
        entry = str(entry)
        if entry in CAPTURE_ENVS or entry in HELDOUT_ENVS:
            name, source = entry, PROCEDURAL
        elif entry.startswith(POLYHAVEN_PREFIX) and not Path(entry).suffix:
            name, source = entry, str(polyhaven_path(entry))
        else:
            path = Path(entry).expanduser()
            if not path.is_file():
                raise FileNotFoundError(f"{path}: environment file not found (nor a known "
                                        "environment name)")
            name, source = path.stem, str(path.resolve())
        if name in out:
            raise ValueError(f"environment name {name!r} appears twice in {list(spec)}")
        out[name] = source
    if not out:
        raise ValueError("an environment set must not be empty")
    return out


def check_disjoint(capture: dict, relight: dict) -> None:
    both = sorted(set(capture) & set(relight))
    if both:
        raise ValueError(f"capture and relighting environments must be disjoint; both hold {both}")


def assign_environments(recipe: dict, seed: int, capture: list[str] | None,
                        relight: list[str] | None, num_relight: int) -> dict:
    """A copy of `recipe` with its capture env (unless `capture` is None) and its
    `num_relight` relight envs (unless `relight` is None) redrawn, each from its own stream:
    changing only the relighting set leaves the input images byte-identical."""
    out = dict(recipe)
    if relight is not None:
        if not 0 <= num_relight <= len(relight):
            raise ValueError(f"num_relight_envs must be in [0, {len(relight)}] for relighting "
                             f"environments {relight}, got {num_relight}")
        rng = scene_rng(seed, recipe["index"], RELIGHT_STREAM)
        pick = sorted(rng.choice(len(relight), size=num_relight, replace=False).tolist())
        out["relight_envs"] = [relight[i] for i in pick]
    if capture is not None:
        rng = scene_rng(seed, recipe["index"], CAPTURE_STREAM)
        out["capture_env"] = capture[int(rng.integers(0, len(capture)))]
    return out


def make_named_environment(name: str, source: str, height: int, *,
                           white_radiance: float = 1.0) -> torch.Tensor:
    """[height, 2 height, 3] float32 environment of `name` from its source."""
    if source == PROCEDURAL:
        return make_environment(name, height, white_radiance=white_radiance)
    return load_hdri(source, height, white_radiance=white_radiance)


def is_default(*specs) -> bool:
    return all(s is None or s == PROCEDURAL for s in specs)



def environment_sets(capture_spec, relight_spec) -> tuple[dict[str, str], dict[str, str]]:
    """Both resolved sets ({name: source}), checked disjoint."""
    capture = resolve_env_set(capture_spec, "capture")
    relight = resolve_env_set(relight_spec, "heldout")
    check_disjoint(capture, relight)
    return capture, relight

"""Densify / prune schedule: gsplat's ``DefaultStrategy`` (3DGS rules), fed from the torch rasterizer.

gsplat 1.5.3's strategy code is pure torch and runs on CPU; it needs, per training step,
``info`` with ``gradient_2dgs`` (or ``means2d``), ``radii`` [C, N, 2], ``width``, ``height``,
``n_cameras`` and ``gaussian_ids``: :func:`gspi.recon.render.render_views` provides exactly
these (see there for how the 2DGS densification gradient is reproduced). Three adaptations:

* Parameters live in gsplat's layout (``means, scales, quats, opacities, sh0, shN``, one
  Adam per tensor). gsplat's ``split`` samples the new centres with ``R @ (s * randn(3))``
  and so needs three scales; the surfels' third (normal-axis) log scale is padded with
  ``log(1e-8)`` -- the rasterizer ignores it -- so children are displaced in the surfel
  plane only, as hbb1's 2DGS ``densify_and_split`` does (it pads the std with 0).
* gsplat 1.5.3 never resets opacities: its test ``step % self.reset_every == 0 & step > 0``
  parses as ``step % reset_every == (0 & step) > 0``, always False. :func:`maybe_reset_opacity`
  does the reset (to ``2 * prune_opa``, inside the refine window, like gsplat intends and
  3DGS does); the trainer calls it after ``step_post_backward``.
* gsplat is an optional dependency (``pip install gsplat==1.5.3``; its CUDA kernels are not
  needed for this). Without it :class:`BuiltinDefaultStrategy`, a line-by-line port of the
  same rules and ops, is used; ``tests/test_recon.py`` checks both agree.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass
from typing import Any, Callable, Dict

import torch
import torch.nn.functional as F
from torch import Tensor

from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.projection import quat_to_rotmat

PAD_LOG_SCALE = math.log(1e-8)  # third (normal-axis) log scale in gsplat's [N, 3] layout
PARAM_NAMES = ("means", "scales", "quats", "opacities", "sh0", "shN")


def gsplat_strategy_available() -> bool:
    try:
        importlib.import_module("gsplat.strategy")
    except Exception:  # ImportError, or a broken CUDA runtime import
        return False
    return True


# ---- Gaussians2D <-> gsplat parameter dict -----------------------------------------------------
def to_params(g: Gaussians2D) -> Dict[str, torch.nn.Parameter]:
    """gsplat-layout parameters (leaf tensors that require grad) of raw surfel parameters."""
    pad = torch.full((g.num_gaussians, 1), PAD_LOG_SCALE, dtype=g.log_scales.dtype, device=g.device)
    values = {"means": g.means, "scales": torch.cat([g.log_scales, pad], 1), "quats": g.quats,
              "opacities": g.opacity_logits, "sh0": g.sh_dc, "shN": g.sh_rest}
    return {k: torch.nn.Parameter(v.detach().clone().contiguous()) for k, v in values.items()}


def from_params(params: Dict[str, Tensor]) -> Gaussians2D:
    """Raw surfel parameters (detached copies) of a gsplat-layout parameter dict."""
    p = {k: v.detach().clone() for k, v in params.items()}
    return Gaussians2D(means=p["means"], quats=p["quats"], log_scales=p["scales"][:, :2].contiguous(),
                       opacity_logits=p["opacities"], sh_dc=p["sh0"], sh_rest=p["shN"])


# ---- builtin port of gsplat.strategy.ops (used without gsplat) --------------------------------
@torch.no_grad()
def _update_param_with_optimizer(param_fn: Callable, optimizer_fn: Callable, params: dict, optimizers: dict,
                                 names=None) -> None:
    for name in (list(params) if names is None else names):
        param = params[name]
        new_param = param_fn(name, param)
        params[name] = new_param
        if name not in optimizers:
            continue
        optimizer = optimizers[name]
        for group in optimizer.param_groups:
            state = optimizer.state.pop(param, {})
            for key in list(state):
                if key != "step":
                    state[key] = optimizer_fn(key, state[key])
            group["params"] = [new_param]
            optimizer.state[new_param] = state


@torch.no_grad()
def _duplicate(params, optimizers, state, mask: Tensor) -> None:
    sel = torch.where(mask)[0]
    _update_param_with_optimizer(
        lambda name, p: torch.nn.Parameter(torch.cat([p, p[sel]]), requires_grad=p.requires_grad),
        lambda key, v: torch.cat([v, torch.zeros((len(sel), *v.shape[1:]), dtype=v.dtype, device=v.device)]),
        params, optimizers)
    for k, v in state.items():
        if isinstance(v, Tensor):
            state[k] = torch.cat((v, v[sel]))


@torch.no_grad()
def _split(params, optimizers, state, mask: Tensor) -> None:
    sel, rest = torch.where(mask)[0], torch.where(~mask)[0]
    scales = torch.exp(params["scales"][sel])
    rotmats = quat_to_rotmat(F.normalize(params["quats"][sel], dim=-1))
    samples = torch.einsum("nij,nj,bnj->bni", rotmats, scales,
                           torch.randn(2, len(scales), 3, device=scales.device))  # [2, N, 3]

    def param_fn(name: str, p: Tensor) -> Tensor:
        repeats = [2] + [1] * (p.dim() - 1)
        if name == "means":
            p_split = (p[sel] + samples).reshape(-1, 3)
        elif name == "scales":
            p_split = torch.log(scales / 1.6).repeat(2, 1)
        else:
            p_split = p[sel].repeat(repeats)
        return torch.nn.Parameter(torch.cat([p[rest], p_split]), requires_grad=p.requires_grad)

    _update_param_with_optimizer(
        param_fn,
        lambda key, v: torch.cat([v[rest], torch.zeros((2 * len(sel), *v.shape[1:]), dtype=v.dtype,
                                                       device=v.device)]),
        params, optimizers)
    for k, v in state.items():
        if isinstance(v, Tensor):
            state[k] = torch.cat((v[rest], v[sel].repeat([2] + [1] * (v.dim() - 1))))


@torch.no_grad()
def _remove(params, optimizers, state, mask: Tensor) -> None:
    sel = torch.where(~mask)[0]
    _update_param_with_optimizer(lambda name, p: torch.nn.Parameter(p[sel], requires_grad=p.requires_grad),
                                 lambda key, v: v[sel], params, optimizers)
    for k, v in state.items():
        if isinstance(v, Tensor):
            state[k] = v[sel]


@torch.no_grad()
def _reset_opa(params, optimizers, state, value: float) -> None:
    logit = math.log(value / (1.0 - value))
    _update_param_with_optimizer(
        lambda name, p: torch.nn.Parameter(torch.clamp(p, max=logit), requires_grad=p.requires_grad),
        lambda key, v: torch.zeros_like(v), params, optimizers, names=["opacities"])


@dataclass
class BuiltinDefaultStrategy:
    """Port of ``gsplat.strategy.DefaultStrategy`` (1.5.3, non-packed, no absgrad, no 2D-scale
    rules) for machines without gsplat; same fields, same state, same results."""

    prune_opa: float = 0.005
    grow_grad2d: float = 0.0002
    grow_scale3d: float = 0.01
    prune_scale3d: float = 0.1
    refine_start_iter: int = 500
    refine_stop_iter: int = 15_000
    reset_every: int = 3000
    refine_every: int = 100
    pause_refine_after_reset: int = 0
    key_for_gradient: str = "gradient_2dgs"
    verbose: bool = False

    def initialize_state(self, scene_scale: float = 1.0) -> Dict[str, Any]:
        return {"grad2d": None, "count": None, "scene_scale": scene_scale}

    def check_sanity(self, params, optimizers) -> None:
        trainable = {n for n, p in params.items() if p.requires_grad}
        assert trainable == set(optimizers), f"params {trainable} vs optimizers {set(optimizers)}"
        for key in ("means", "scales", "quats", "opacities"):
            assert key in params, f"{key} is required in params but missing."

    def step_pre_backward(self, params, optimizers, state, step: int, info: dict) -> None:
        info[self.key_for_gradient].retain_grad()

    def step_post_backward(self, params, optimizers, state, step: int, info: dict, packed: bool = False) -> None:
        if step >= self.refine_stop_iter:
            return
        self._update_state(params, state, info)
        if (step > self.refine_start_iter and step % self.refine_every == 0
                and step % self.reset_every >= self.pause_refine_after_reset):
            is_grad_high = state["grad2d"] / state["count"].clamp_min(1) > self.grow_grad2d
            is_small = torch.exp(params["scales"]).max(dim=-1).values <= self.grow_scale3d * state["scene_scale"]
            is_dupli = is_grad_high & is_small
            n_dupli = int(is_dupli.sum())
            if n_dupli > 0:
                _duplicate(params, optimizers, state, is_dupli)
            is_split = torch.cat([is_grad_high & ~is_small, torch.zeros(n_dupli, dtype=torch.bool, device=is_small.device)])
            if is_split.any():
                _split(params, optimizers, state, is_split)
            is_prune = torch.sigmoid(params["opacities"].flatten()) < self.prune_opa
            if step > self.reset_every:
                is_prune |= torch.exp(params["scales"]).max(dim=-1).values > self.prune_scale3d * state["scene_scale"]
            if is_prune.any():
                _remove(params, optimizers, state, is_prune)
            state["grad2d"].zero_()
            state["count"].zero_()
        # (no opacity reset here: gsplat 1.5.3 never performs it, see maybe_reset_opacity)

    def _update_state(self, params, state, info) -> None:
        grads = info[self.key_for_gradient].grad.clone()
        grads[..., 0] *= info["width"] / 2.0 * info["n_cameras"]
        grads[..., 1] *= info["height"] / 2.0 * info["n_cameras"]
        n = len(params["means"])
        if state["grad2d"] is None:
            state["grad2d"] = torch.zeros(n, device=grads.device)
        if state["count"] is None:
            state["count"] = torch.zeros(n, device=grads.device)
        sel = (info["radii"] > 0.0).all(dim=-1)  # [C, N]
        gs_ids = torch.where(sel)[1]
        state["grad2d"].index_add_(0, gs_ids, grads[sel].norm(dim=-1))
        state["count"].index_add_(0, gs_ids, torch.ones_like(gs_ids, dtype=torch.float32))


STRATEGY_FIELDS = ("prune_opa", "grow_grad2d", "grow_scale3d", "prune_scale3d", "refine_start_iter",
                   "refine_stop_iter", "reset_every", "refine_every", "pause_refine_after_reset")


def make_strategy(cfg: dict, impl: str = "auto"):
    """The densification strategy: (strategy, name); ``impl`` in auto | gsplat | builtin."""
    kwargs = {k: cfg[k] for k in STRATEGY_FIELDS if k in cfg}
    kwargs["key_for_gradient"] = "gradient_2dgs"
    if impl not in ("auto", "gsplat", "builtin"):
        raise ValueError(f"densify.impl must be auto, gsplat or builtin, got {impl!r}")
    if impl == "gsplat" or (impl == "auto" and gsplat_strategy_available()):
        import gsplat
        from gsplat.strategy import DefaultStrategy

        return DefaultStrategy(**kwargs), f"gsplat.strategy.DefaultStrategy (gsplat {gsplat.__version__})"
    return BuiltinDefaultStrategy(**kwargs), "gspi.recon.strategy.BuiltinDefaultStrategy (port of gsplat 1.5.3)"


def reset_opacity(params, optimizers, state, value: float) -> None:
    """Clamp opacities to ``value`` and zero their Adam moments (gsplat's ``reset_opa``)."""
    _reset_opa(params, optimizers, state, value)


def maybe_reset_opacity(strategy, params, optimizers, state, step: int) -> bool:
    """The opacity reset gsplat 1.5.3 intends but never runs: every ``reset_every`` steps
    (step > 0) inside the refine window, to ``2 * prune_opa``. Returns True when it reset."""
    if 0 < step < strategy.refine_stop_iter and step % strategy.reset_every == 0:
        reset_opacity(params, optimizers, state, 2.0 * strategy.prune_opa)
        return True
    return False

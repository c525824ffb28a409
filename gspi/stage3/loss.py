"""The masked distillation objective of Stage III (paper, Eq. L_distill).

    L = 1 / (N_v sum_p w_p) * sum_v sum_p w_p [ (1 - lambda) (L1_pv + L2_pv) / 2 + lambda (1 - SSIM_pv) ]

over properties p in {albedo, roughness, metallic} and the N_v views of the batch whose mask
B_v is not empty. Per view v and property p, with B_v the binary foreground mask:

* ``L1_pv``: mean absolute difference over the pixels of B_v and the property's channels;
* ``L2_pv``: mean squared difference, same pixels and channels;
* ``SSIM_pv``: the evaluator's masked SSIM (``eval.metrics``: Gaussian window 11, sigma 1.5,
  both images composited on 0 outside B_v, the valid-window SSIM map averaged over the
  pixels of B_v at least 5 pixels from the border, then over channels), in differentiable
  torch. A view whose mask has no such pixel contributes 1 - SSIM = 0.

Pixels outside B_v cannot change the loss. Albedo is compared sRGB-encoded (see render.py).

Round-off snap: where ``|pred - target| <= snap_tolerance`` (default 1e-6, far below the 1.5e-5
step of the 16-bit targets) the prediction is replaced by the (constant) target before the
terms are computed. Dividing the composite by alpha leaves float32 round-off of a few 1e-8 even
when every surfel holds the target value exactly; L1's sign gradient and SSIM's gradient of that
noise, rescaled by Adam to full learning-rate steps, would otherwise walk an exact fit away.
"""
from __future__ import annotations

from typing import Mapping

import torch
from torch import Tensor

from eval.metrics import SSIM_WINDOW, composite, ssim_map

PROPERTIES = ("albedo", "roughness", "metallic")


def inner_ssim(pred: Tensor, target: Tensor, mask: Tensor) -> Tensor | None:
    """[M, C] SSIM values of an [H, W, C] image pair at the M pixels of the [H, W] bool mask at
    least the window radius from the border (``eval.metrics.ssim_map``, both images composited
    on 0 outside the mask), in row-major order; None if there is no such pixel.

    Computed on the mask's bounding box grown by the window radius: every window centred on
    such a pixel lies inside it, so the values are those of the full-image map, bit for bit
    (a Stage III step spent ~3 ms of its ~35 ms in the full-image convolutions at 128 px).
    """
    r = SSIM_WINDOW // 2
    h, w = mask.shape
    rows, cols = torch.nonzero(mask.any(1))[:, 0], torch.nonzero(mask.any(0))[:, 0]
    if len(rows) == 0:
        return None
    y0, y1 = max(int(rows[0]) - r, 0), min(int(rows[-1]) + r + 1, h)
    x0, x1 = max(int(cols[0]) - r, 0), min(int(cols[-1]) + r + 1, w)
    box = mask[y0:y1, x0:x1]
    inner = box[r:box.shape[0] - r, r:box.shape[1] - r]
    if not inner.any():
        return None
    s = ssim_map(composite(pred[y0:y1, x0:x1], box, 0.0), composite(target[y0:y1, x0:x1], box, 0.0))
    return s[inner]


def dssim_per_property(pred: Mapping[str, Tensor], target: Mapping[str, Tensor], mask: Tensor
                       ) -> dict[str, Tensor]:
    """1 - masked SSIM of each property of one view ([H, W, C] maps, [H, W] bool mask; 0 where the
    mask has no inner pixel), from one SSIM map of their stacked channels (SSIM is per channel:
    the same values as one map per property, a third of the calls)."""
    s = inner_ssim(torch.cat([pred[p] for p in PROPERTIES], -1), torch.cat([target[p] for p in PROPERTIES], -1),
                   mask)
    out, start = {}, 0
    for p in PROPERTIES:
        c = pred[p].shape[-1]
        out[p] = pred[p].new_zeros(()) if s is None else 1.0 - s[:, start:start + c].contiguous().mean()
        start += c
    return out


def masked_material_loss(pred: Mapping[str, Tensor], target: Mapping[str, Tensor], mask: Tensor, *,
                         weights: Mapping[str, float], ssim_lambda: float,
                         snap_tolerance: float = 1e-6) -> tuple[Tensor, dict]:
    """The paper's L_distill on a batch of views.

    Args:
        pred: {"albedo": [V, H, W, 3], "roughness": [V, H, W, 1], "metallic": [V, H, W, 1]}
            rendered maps in [0, 1] (albedo sRGB-encoded).
        target: the same keys and shapes, staged targets.
        mask: [V, H, W] bool foreground B_v.
        weights: {"albedo": w_a, "roughness": w_r, "metallic": w_m}.
        ssim_lambda: lambda in [0, 1].
        snap_tolerance: differences at most this are round-off and count as 0 (module docstring).

    Returns:
        (scalar loss, terms: per property p "<p>/l1", "<p>/l2", "<p>/dssim" (means over the
        views with a non-empty mask) and "views" N_v, all Python numbers).

    Raises:
        ValueError: on a missing property, a shape mismatch or an all-empty mask.
    """
    mask = mask.bool()
    for p in PROPERTIES:
        if p not in pred or p not in target or p not in weights:
            raise ValueError(f"masked_material_loss needs {p!r} in pred, target and weights")
        if pred[p].shape != target[p].shape or pred[p].shape[:3] != mask.shape:
            raise ValueError(f"{p}: pred {tuple(pred[p].shape)}, target {tuple(target[p].shape)} and "
                             f"mask {tuple(mask.shape)} do not match")
    views = [v for v in range(mask.shape[0]) if mask[v].any()]
    if not views:
        raise ValueError("masked_material_loss: every view's mask is empty")
    total = pred["albedo"].new_zeros(())
    terms: dict = {"views": len(views)}
    goal = {p: target[p].detach() for p in PROPERTIES}
    snapped = {p: torch.where((pred[p] - goal[p]).abs() <= snap_tolerance, goal[p], pred[p]) for p in PROPERTIES}
    dssims = {v: dssim_per_property({p: snapped[p][v] for p in PROPERTIES}, {p: goal[p][v] for p in PROPERTIES},
                                    mask[v]) for v in views} if ssim_lambda > 0 else {}
    for p in PROPERTIES:
        sums = {"l1": 0.0, "l2": 0.0, "dssim": 0.0}
        for v in views:
            diff = (snapped[p][v] - goal[p][v])[mask[v]]  # [M, C]
            l1, l2 = diff.abs().mean(), (diff * diff).mean()
            dssim = dssims[v][p] if ssim_lambda > 0 else l1.new_zeros(())
            total = total + weights[p] * ((1.0 - ssim_lambda) * 0.5 * (l1 + l2) + ssim_lambda * dssim)
            for key, value in (("l1", l1), ("l2", l2), ("dssim", dssim)):
                sums[key] += float(value.detach())
        terms.update({f"{p}/{key}": value / len(views) for key, value in sums.items()})
    loss = total / (len(views) * sum(weights[p] for p in PROPERTIES))
    return loss, terms

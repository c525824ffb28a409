"""Inputs shared by the preset goldens' recorder (tests/golden/record_presets.py) and their test
(tests/test_preset_goldens.py): small scenes of albedo maps and relit images on which each
project's own evaluation code was run once.

Values are *as stored* (an albedo.png's values, a display image's values) or linear radiance
(relit). Each case stresses one convention:

- ``clean``: three views, the object inside the image, prediction = GT with a per-channel
  gain and noise, black outside the mask;
- ``border``: the object touches the image border (SSIM padding);
- ``clip``: a dim prediction of a bright GT, so the aligned values pass 1 (clamping), and GT
  pixels with a zero channel inside the mask (IRGS fits its scale only where GT > 0);
- ``junk``: the prediction holds noise outside the mask (masked vs unmasked prediction).
"""
from __future__ import annotations

import torch

HEIGHT, WIDTH, VIEWS = 40, 48, 3
CASES = ("clean", "border", "clip", "junk")
RELIT_ENVS = ("env_a", "env_b")


def _generator(case: str, salt: int) -> torch.Generator:
    return torch.Generator().manual_seed(1000 * (CASES.index(case) + 1) + salt)


def view_mask(case: str, view: int) -> torch.Tensor:
    """[H, W] bool: an ellipse, shifted per view; in ``border`` it crosses the right edge."""
    y, x = torch.meshgrid(torch.arange(HEIGHT, dtype=torch.float64),
                          torch.arange(WIDTH, dtype=torch.float64), indexing="ij")
    cx = (WIDTH - 4.0 if case == "border" else 22.0 + 2 * view)
    cy, rx, ry = 19.0 + view, 13.0, 11.0 - view
    return ((x - cx) / rx) ** 2 + ((y - cy) / ry) ** 2 <= 1.0


def _smooth_field(g: torch.Generator, lo: float, hi: float) -> torch.Tensor:
    """[H, W, 3] low-frequency colours in [lo, hi] (bilinear upsampling of a 6 x 7 grid)."""
    coarse = torch.rand(1, 3, 6, 7, generator=g, dtype=torch.float64)
    fine = torch.nn.functional.interpolate(coarse, size=(HEIGHT, WIDTH), mode="bilinear", align_corners=True)
    return lo + (hi - lo) * fine[0].permute(1, 2, 0)


def albedo_case(case: str) -> dict[str, list[torch.Tensor]]:
    """{"gt", "pred": [H, W, 3] float64 stored values per view, "mask": [H, W] bool per view}.
    The GT is 0 outside the mask (as gspi's GT albedo.png)."""
    g = _generator(case, 0)
    gain = torch.tensor([0.5, 0.55, 0.6] if case == "clip" else [0.7, 0.9, 1.2], dtype=torch.float64)
    out = {"gt": [], "pred": [], "mask": []}
    for v in range(VIEWS):
        m = view_mask(case, v)
        gt = _smooth_field(g, 0.55, 0.98) if case == "clip" else _smooth_field(g, 0.08, 0.9)
        if case == "clip":
            gt[..., 2] = torch.where(torch.rand(HEIGHT, WIDTH, generator=g) < 0.1, 0.0, gt[..., 2])
        noise = 0.03 * torch.randn(HEIGHT, WIDTH, 3, generator=g, dtype=torch.float64)
        pred = (gt * gain + noise).clamp(0.0, 1.0)
        outside = torch.rand(HEIGHT, WIDTH, 3, generator=g, dtype=torch.float64) if case == "junk" else 0.0
        out["gt"].append(torch.where(m[..., None], gt, torch.zeros_like(gt)))
        out["pred"].append(torch.where(m[..., None], pred, outside * torch.ones_like(pred)))
        out["mask"].append(m)
    return out


def relit_case(case: str) -> dict[str, list]:
    """{"gt", "pred": [view][env] [H, W, 3] float64 linear radiance (0 outside the mask, some
    above 1), "mask": [H, W] bool per view}."""
    g = _generator(case, 1)
    out = {"gt": [], "pred": [], "mask": []}
    for v in range(VIEWS):
        m = view_mask(case, v)[..., None]
        gts, preds = [], []
        for _ in RELIT_ENVS:
            gt = _smooth_field(g, 0.02, 1.5)
            pred = (0.85 * gt + 0.05 * torch.randn(HEIGHT, WIDTH, 3, generator=g, dtype=torch.float64)).clamp_min(0.0)
            gts.append(torch.where(m, gt, torch.zeros_like(gt)))
            preds.append(torch.where(m, pred, torch.zeros_like(pred)))
        out["gt"].append(gts)
        out["pred"].append(preds)
        out["mask"].append(m[..., 0])
    return out

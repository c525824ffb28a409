"""One image pair -> its scores under a protocol (docs/PROTOCOL.md, "Scoring one image").

`score_pair` applies the protocol's PSNR region and floors, SSIM window and region, LPIPS
options; `score_relit` first applies the relighting steps (per-image scale fit, tone map) and
adds Stanford-ORB's PSNR-H when asked; `metal_scores` gives the metallic MAE and metal-mask
IoU. The mask passed in is already the scored (possibly eroded) ground-truth mask.
"""
from __future__ import annotations

from torch import Tensor

from eval.colorspace import linear_to_srgb, srgb_to_linear
from eval.metrics import (grey_psnr, masked_iou, masked_lpips, masked_mae, masked_mse,
                          masked_ssim, psnr_from_mse)
from eval.scored_view import RelitPair, relit_pair


def psnr_scores(pred: Tensor, gt: Tensor, mask: Tensor, psnr_cfg) -> tuple[float, bool]:
    """(PSNR in dB, whether the MSE floor was hit) under `protocol.psnr`."""
    floor = float(psnr_cfg.mse_floor)
    mse = masked_mse(pred, gt, mask, region=psnr_cfg.region)
    psnr = psnr_from_mse(mse, mse_floor=floor)
    if psnr_cfg.grey_floor:
        psnr = max(psnr, grey_psnr(gt, mask, region=psnr_cfg.region, mse_floor=floor))
    return psnr, mse <= floor


def scored_space(channel: str, pred: Tensor, gt: Tensor, protocol) -> tuple[Tensor, Tensor, bool]:
    """(pred, gt) in the colour space the protocol scores ``channel`` in (albedo: ``albedo_space``;
    maps are stored sRGB-encoded), and whether LPIPS sRGB-encodes them again first."""
    if channel == "albedo" and protocol.albedo_space == "linear":
        return srgb_to_linear(pred.double()), srgb_to_linear(gt.double()), bool(protocol.lpips.encode_srgb)
    return pred, gt, False


def score_pair(pred: Tensor, gt: Tensor, mask: Tensor, protocol, net, *,
               lpips_srgb: bool = False) -> dict:
    """{psnr, psnr_floored, ssim, lpips} of [H, W, C] images in the scored colour space.

    Args:
        lpips_srgb: sRGB-encode both images before LPIPS (protocol.lpips.encode_srgb, albedo
            and relight only).
    """
    psnr, floored = psnr_scores(pred, gt, mask, protocol.psnr)
    lp_pred, lp_gt = (linear_to_srgb(pred), linear_to_srgb(gt)) if lpips_srgb else (pred, gt)
    return {"psnr": psnr, "psnr_floored": floored,
            "ssim": masked_ssim(pred, gt, mask, background=protocol.background,
                                window=int(protocol.ssim.window), region=protocol.ssim.region,
                                padding=protocol.ssim.padding),
            "lpips": masked_lpips(lp_pred, lp_gt, mask, net=net, mode=protocol.lpips.mode,
                                  background=protocol.background,
                                  normalize=bool(protocol.lpips.normalize))}


def psnr_hdr(out_linear: Tensor, ref_linear: Tensor, mask: Tensor, relight_cfg, psnr_cfg
             ) -> float:
    """Stanford-ORB's PSNR-H on linear radiance: both images multiplied by the mask, optionally
    renormalised by mean(srgb(clip(gt, 0, 1))) / mean(clip(gt, 0, 1)), clipped to
    [0, hdr_max], then PSNR with data range 1 (as its `mse_to_psnr`)."""
    m = mask[..., None].double()
    p, g = out_linear.double() * m, ref_linear.double().clamp_min(0.0) * m
    if relight_cfg.hdr_gt_renorm:
        g01 = g.clamp(0.0, 1.0)
        if float(g01.mean()) > 1e-8:
            k = linear_to_srgb(g01).mean() / g01.mean()
            p, g = p * k, g * k
    hi = float(relight_cfg.hdr_max)
    return psnr_scores(p.clamp(0.0, hi), g.clamp(0.0, hi), mask, psnr_cfg)[0]


def score_relit(out_linear: Tensor, ref_linear: Tensor, mask: Tensor, protocol, net) -> dict:
    """Scores of one relit view: the prediction `out_linear` against `ref_linear` ([H, W, 3]
    linear radiance), after the protocol's scale fit and tone map; `psnr_h` if asked."""
    return score_relit_pair(relit_pair(out_linear, ref_linear, mask, protocol.relight), mask, protocol, net)


def score_relit_pair(pair: RelitPair, mask: Tensor, protocol, net) -> dict:
    """Scores of a relit view already through the protocol's steps (``eval.scored_view.relit_pair``)."""
    row = score_pair(pair.pred, pair.gt, mask, protocol, net, lpips_srgb=bool(protocol.lpips.encode_srgb))
    if protocol.relight.psnr_hdr:
        row["psnr_h"] = psnr_hdr(pair.pred_linear, pair.gt_linear, mask, protocol.relight, protocol.psnr)
    return row


def has_metal(gt_metallic: list[Tensor], masks: list[Tensor], threshold: float) -> bool:
    """True when any masked ground-truth pixel of the scene is metal (> threshold)."""
    return any(bool((g[..., 0] > threshold)[m].any()) for g, m in zip(gt_metallic, masks))


def metal_scores(pred: Tensor, gt: Tensor, mask: Tensor, metallic_cfg) -> dict:
    """{mae, iou} of a metallic map (IoU of the metal masks at `metallic.threshold`)."""
    return {"mae": masked_mae(pred, gt, mask),
            "iou": masked_iou(pred, gt, mask, threshold=float(metallic_cfg.threshold))}

"""One image pair -> its scores under a protocol (docs/PROTOCOL.md, "Scoring one image").

`score_pair` applies the protocol's PSNR region and floors, SSIM window and region, LPIPS
options; `score_relit` first applies the relighting steps (per-image scale fit, tone map) and
adds Stanford-ORB's PSNR-H when asked; `metal_scores` gives the metallic MAE and metal-mask
IoU. The mask passed in is already the scored (possibly eroded) ground-truth mask.
"""
from __future__ import annotations

from torch import Tensor

from eval.common.colorspace import linear_to_srgb, srgb_to_linear
from eval.metrics import (grey_psnr, masked_iou, masked_lpips, masked_mae, masked_ssim,
                          psnr_from_mse, squared_error_terms)
from eval.scored_view import RelitPair, relit_pair


def psnr_from_terms(sse: Tensor, count: int, psnr_cfg) -> tuple[float, bool]:
    """(PSNR in dB, whether the MSE floor was hit) from squared-error sums per channel
    (``eval.metrics.squared_error_terms``, of one view or pooled over several): one MSE over
    all channels, or with ``psnr.channel_mean`` the mean of the per-channel PSNRs (GS-IR's and
    IRGS's ``psnr`` on a [3, H, W] image: ``view(shape[0], -1)`` makes one PSNR per channel)."""
    floor = float(psnr_cfg.mse_floor)
    if psnr_cfg.channel_mean:
        mses = [float(x) / count for x in sse]
        return sum(psnr_from_mse(m, mse_floor=floor) for m in mses) / len(mses), min(mses) <= floor
    mse = float(sse.sum()) / (count * sse.numel())
    return psnr_from_mse(mse, mse_floor=floor), mse <= floor


def psnr_scores(pred: Tensor, gt: Tensor, mask: Tensor, psnr_cfg, *, mask_pred: bool = True
                ) -> tuple[float, bool]:
    """(PSNR in dB, whether the MSE floor was hit) under `protocol.psnr`."""
    psnr, floored = psnr_from_terms(*squared_error_terms(pred, gt, mask, region=psnr_cfg.region,
                                                         mask_pred=mask_pred), psnr_cfg)
    if psnr_cfg.grey_floor:
        psnr = max(psnr, grey_psnr(gt, mask, region=psnr_cfg.region, mse_floor=float(psnr_cfg.mse_floor)))
    return psnr, floored


METRIC_NAMES = ("psnr", "ssim", "lpips")


def encode_albedo(albedo: Tensor, space: str) -> Tensor:
    """An albedo as stored (sRGB-encoded) in the space a metric reads: ``srgb`` as stored,
    ``linear`` decoded (past 1 where an unclamped alignment put it), ``linear_gamma22`` the
    linear values raised to 1/2.2 (TensoIR: its albedo PNG holds linear values, encoded with
    x^(1/2.2) for its albedo PSNR), ``gamma22`` the stored values raised to 1/2.2."""
    if space == "srgb":
        return albedo
    if space == "linear":
        return srgb_to_linear(albedo.double().clamp_min(0.0), clamp=False)
    if space == "linear_gamma22":
        return encode_albedo(albedo, "linear") ** (1.0 / 2.2)
    if space == "gamma22":
        return albedo.double().clamp_min(0.0) ** (1.0 / 2.2)
    raise ValueError(f"unknown albedo space {space!r}; allowed: srgb, linear, linear_gamma22, gamma22")


def metric_space(protocol, metric: str) -> str:
    """The colour space albedo is scored in by ``metric``: its own ``<metric>.albedo_space``,
    else the protocol's ``albedo_space``."""
    return getattr(protocol, metric).albedo_space or protocol.albedo_space


def scored_space(channel: str, pred: Tensor, gt: Tensor, protocol, metric: str = "psnr"
                 ) -> tuple[Tensor, Tensor, bool]:
    """(pred, gt) in the colour space the protocol scores ``channel`` in with ``metric``
    (albedo: ``metric_space``; maps are stored sRGB-encoded), and whether LPIPS sRGB-encodes
    them again first (``lpips.encode_srgb``, for albedo scored linear)."""
    if channel != "albedo":
        return pred, gt, False
    space = metric_space(protocol, metric)
    again = space == "linear" and bool(protocol.lpips.encode_srgb)
    return encode_albedo(pred, space), encode_albedo(gt, space), again


def score_images(images: dict[str, tuple[Tensor, Tensor]], mask: Tensor, protocol, net, *,
                 lpips_srgb: bool = False) -> dict:
    """{psnr, psnr_floored, ssim, lpips} of [H, W, C] image pairs, one pair per metric
    (``images[metric] = (pred, gt)`` in the space that metric reads)."""
    keep = bool(protocol.mask_prediction)
    psnr, floored = psnr_scores(*images["psnr"], mask, protocol.psnr, mask_pred=keep)
    lp_pred, lp_gt = images["lpips"]
    if lpips_srgb:
        lp_pred, lp_gt = linear_to_srgb(lp_pred), linear_to_srgb(lp_gt)
    return {"psnr": psnr, "psnr_floored": floored,
            "ssim": masked_ssim(*images["ssim"], mask, background=protocol.background,
                                window=int(protocol.ssim.window), region=protocol.ssim.region,
                                padding=protocol.ssim.padding, mask_pred=keep),
            "lpips": masked_lpips(lp_pred, lp_gt, mask, net=net, mode=protocol.lpips.mode,
                                  background=protocol.background,
                                  normalize=bool(protocol.lpips.normalize), mask_pred=keep)}


def score_pair(pred: Tensor, gt: Tensor, mask: Tensor, protocol, net, *,
               lpips_srgb: bool = False) -> dict:
    """{psnr, psnr_floored, ssim, lpips} of one [H, W, C] image pair in the scored colour space.

    Args:
        lpips_srgb: sRGB-encode both images before LPIPS (protocol.lpips.encode_srgb, albedo
            and relight only).
    """
    return score_images({m: (pred, gt) for m in METRIC_NAMES}, mask, protocol, net, lpips_srgb=lpips_srgb)


def score_map(channel: str, pred: Tensor, gt: Tensor, mask: Tensor, protocol, net) -> dict:
    """Scores of one material map; albedo in each metric's colour space (``scored_space``)."""
    images, lpips_srgb = {}, False
    for metric in METRIC_NAMES:
        p, g, again = scored_space(channel, pred, gt, protocol, metric)
        images[metric] = (p, g)
        if metric == "lpips":
            lpips_srgb = again
    return score_images(images, mask, protocol, net, lpips_srgb=lpips_srgb)


def pooled_psnr(channel: str, preds: list[Tensor], gts: list[Tensor], masks: list[Tensor], protocol
                ) -> tuple[float, bool]:
    """PSNR of one MSE pooled over a scene's views (``psnr.map_pooling: scene``: TensoIR's
    albedo PSNR, ``np.mean`` over the stacked views of a scene)."""
    total, count = None, 0
    for pred, gt, mask in zip(preds, gts, masks):
        p, g, _ = scored_space(channel, pred, gt, protocol, "psnr")
        sse, n = squared_error_terms(p, g, mask, region=protocol.psnr.region,
                                     mask_pred=bool(protocol.mask_prediction))
        total, count = (sse if total is None else total + sse), count + n
    return psnr_from_terms(total, count, protocol.psnr)


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

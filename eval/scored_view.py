"""A view *as the protocol scores it*: the one definition that the scorer (``eval.evaluate``),
the HTML report's panels (``eval.report_site.panels``) and the run figure
(``eval.report_site.run_figure``) all consume, so that what a user sees is what was scored.

For one scene and prediction folder, ``scene_scored_views`` reads the ground truth and the
prediction of every view of the scored split and applies, in the protocol's order:

1. the scored mask: the GT mask eroded by ``mask_erosion_px``;
2. ``unpremultiply`` by the prediction's ``alpha.png`` where the protocol asks for it;
3. the albedo alignment (``albedo_scales`` then ``apply_scales``: ``albedo_alignment`` pooled over the scene's views or
   per view, ``alignment_scope``);
4. per relighting environment: the GT and predicted relit radiance (GT normals, the aligned or
   raw albedo as ``relight.apply_albedo_alignment`` says, fills for unmodelled channels), the
   relit scale fit (``relight.scale_fit``) and the display transform (``relight.tonemap``):
   ``RelitPair``, the images ``score_pair`` receives.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np
import torch
from torch import Tensor

from eval.common.imageio import read_exr
from eval.common.layout import MATERIAL_CHANNELS, LayoutError, Scene, material_file, read_view_file
from eval.metrics import erode_mask
from eval.protocol import apply_albedo_scale, display_relit, fit_albedo_scale, unclamped_linear_albedo
from eval.protocol_id import scored_split
from eval.unpremultiply import unpremultiply
from eval.views import relight_view, view_directions

CPU = torch.device("cpu")
SCALE_EPS = 1e-6  # Stanford-ORB: a channel with sum(pred^2) <= 1e-6 is left unscaled


def as_tensor(arr: np.ndarray, device: torch.device = CPU) -> Tensor:
    return torch.from_numpy(np.ascontiguousarray(arr)).to(device)


@dataclass
class RelitPair:
    """One environment's relit images: display values as scored, and the linear radiance
    after the scale fit (what Stanford-ORB's PSNR-H reads)."""

    pred: Tensor         # [H, W, 3] display values of the prediction
    gt: Tensor           # [H, W, 3] display values of the ground truth
    pred_linear: Tensor  # [H, W, 3] predicted radiance after the scale fit
    gt_linear: Tensor    # [H, W, 3] GT radiance


@dataclass
class ScoredView:
    """The ground truth and prediction of one view exactly as the protocol scores them."""

    scene: str
    view: str
    mask: Tensor                  # [H, W] bool: the scored (eroded) GT mask
    gt: dict[str, Tensor]         # albedo, roughness, metallic, normal, view_dir
    pred: dict[str, Tensor]       # the channels present; albedo = the aligned albedo as scored
    relit: dict[str, RelitPair] = field(default_factory=dict)  # env -> images ("relight" scored)
    unpremultiplied: bool = False


class EnvironmentCache:
    """Prefiltered environments, built on first use on ``device``, one per distinct map: files
    with the same pixels (each scene of a dataset carries its own copy of a shared
    environment) share one prefiltering, the costly step of relighting."""

    def __init__(self, device: torch.device = CPU):
        self._envs: dict[Path, object] = {}
        self._by_content: dict[tuple, object] = {}
        self.device = torch.device(device)

    def get(self, path: Path):
        if path not in self._envs:
            from eval.relight import prefilter_environment
            pixels = np.ascontiguousarray(read_exr(path))
            key = (pixels.shape, pixels.dtype.str, hashlib.blake2b(pixels.tobytes(), digest_size=16).hexdigest())
            if key not in self._by_content:
                self._by_content[key] = prefilter_environment(as_tensor(pixels, self.device))
            self._envs[path] = self._by_content[key]
        return self._envs[path]


def load_gt_view(scene: Scene, view, device: torch.device = CPU) -> dict:
    """The view's GT maps that exist (``scene.view_gt_channels``; normals where it has relit
    ground truth, or all maps), its mask and view directions."""
    vdir = scene.view_dir(view.split, view.id)
    size = (scene.height, scene.width)
    have = scene.view_gt_channels(view)
    out = {name: as_tensor(read_view_file(vdir, f"{name}.png", size), device)
           for name in MATERIAL_CHANNELS if name in have}
    if "relight" in have or (vdir / "normal.exr").exists():
        out["normal"] = as_tensor(read_view_file(vdir, "normal.exr", size), device)
    out["mask"] = as_tensor(read_view_file(vdir, "mask.png", size), device)[..., 0] > 0.5
    if not out["mask"].any():
        raise LayoutError(f"{vdir / 'mask.png'}: empty foreground mask")
    if (vdir / "outside_brdf.png").is_file():  # optional (glTF imports with BLEND / KHR_materials_*)
        out["outside_brdf"] = as_tensor(read_view_file(vdir, "outside_brdf.png", size), device)[..., 0] > 0.5
    for name, t in out.items():
        if t.shape[:2] != (scene.height, scene.width):
            raise LayoutError(f"{vdir}/{name}: size {tuple(t.shape[:2])} != scene "
                              f"{scene.height}x{scene.width} in scene.json")
    out["view_dir"] = view_directions(view.K, view.w2c, scene.height, scene.width).to(device)
    return out


def load_stored_relit(scene: Scene, view, env_names, device: torch.device = CPU) -> dict:
    """env -> the view's stored relit ground truth (``relit_<env>.exr``, linear) [H, W, 3], for
    ``relight.reference: stored``; an error naming the file when one is absent."""
    vdir = scene.view_dir(view.split, view.id)
    out = {}
    for name in env_names:
        path = vdir / f"relit_{name}.exr"
        if not path.is_file():
            raise LayoutError(f"{path}: not found (the relit ground truth is read from the stored images under "
                              f"eval.relight.reference=stored or scene.json relit_gt: images; datasets write "
                              f"them for their test views only)")
        out[name] = as_tensor(read_exr(path, shape=(scene.height, scene.width)), device)
    return out


def load_pred_view(pred_dir: Path, shape: tuple[int, int], device: torch.device = CPU) -> dict:
    out = {}
    for name in MATERIAL_CHANNELS:
        path = pred_dir / material_file(name)
        if path.exists() or path.is_symlink():  # a broken or looping link is an error, not "absent"
            arr = read_view_file(pred_dir, material_file(name), shape)
            if arr.shape[:2] != shape:
                raise LayoutError(f"{path}: size {arr.shape[:2]} != ground truth {shape}")
            out[name] = as_tensor(arr, device)
    if (pred_dir / "alpha.png").exists():  # the method's own opacity (eval.unpremultiply)
        out["alpha"] = as_tensor(read_view_file(pred_dir, "alpha.png", shape), device)
    return out


def wholly_outside_brdf(g: dict) -> bool:
    """True when every GT-mask pixel of the view is in its outside_brdf.png (e.g. a clearcoat
    object): under ``outside_brdf: exclude`` such a view is not scored (not an error)."""
    return "outside_brdf" in g and not (g["mask"] & ~g["outside_brdf"]).any()


def scored_mask(where: str, mask: Tensor, protocol, outside_brdf: Tensor | None = None) -> Tensor:
    """The GT mask eroded by `mask_erosion_px`, less the `outside_brdf` pixels when the protocol
    excludes them; an error naming the view if nothing is left."""
    eroded = erode_mask(mask, int(protocol.mask_erosion_px))
    if outside_brdf is not None and protocol.outside_brdf == "exclude":
        eroded = eroded & ~outside_brdf
    if not eroded.any():
        excluded = outside_brdf is not None and protocol.outside_brdf == "exclude"
        raise LayoutError(f"{where}: mask empty after eroding {protocol.mask_erosion_px} px"
                          f"{' and leaving out outside_brdf.png' if excluded else ''}")
    return eroded


def sampled_view_indices(n: int, k: int | None) -> list[int]:
    """Views the scene-scope alignment pools: all, or TensoIR's ``compute_rescale_ratio``
    sample ``i * (n // k)`` for ``i < k`` (with fewer than k views that is view 0, k times)."""
    return list(range(n)) if k is None else [i * (n // k) for i in range(k)]


def albedo_scales(pred: list[Tensor], gt: list[Tensor], masks: list[Tensor], mode: str, scope: str, *,
                  space: str = "linear", pixels: str = "mask", sampled_views: int | None = None
                  ) -> list[Tensor]:
    """The [3] alignment scale of each view: one fitted over the scene's (sampled) views
    (``scope="scene"``) or one per view (``"view"``), on the GT-mask pixels (``pixels="mask"``)
    or those whose GT is > 0 in every channel too (``"mask_positive_gt"``, IRGS)."""
    if not pred:
        return []
    if pixels == "mask_positive_gt":
        masks = [m & (g > 0).all(dim=-1) for m, g in zip(masks, gt)]
    elif pixels != "mask":
        raise ValueError(f"eval.alignment_pixels={pixels!r}; allowed: mask, mask_positive_gt")
    if scope == "scene":
        idx = sampled_view_indices(len(pred), sampled_views)
        scale = fit_albedo_scale([pred[i] for i in idx], [gt[i] for i in idx], [masks[i] for i in idx],
                                 mode, space)
        return [scale] * len(pred)
    if scope != "view":
        raise ValueError(f"eval.alignment_scope={scope!r}; allowed: scene, view")
    return [fit_albedo_scale([p], [g], [m], mode, space) for p, g, m in zip(pred, gt, masks)]


def protocol_alignment(protocol) -> dict:
    """The keyword arguments of ``albedo_scales`` a protocol sets."""
    return {"space": protocol.alignment_space, "pixels": protocol.alignment_pixels,
            "sampled_views": protocol.alignment_sampled_views}


def apply_scales(pred: list[Tensor], scales: list[Tensor], masks: list[Tensor], *, space: str = "linear",
                 clamp: bool = True) -> list[Tensor]:
    """Each view's albedo after the alignment: scaled inside its GT mask (outside it the
    prediction is left as it is, as GS-IR's ``albedo_map[mask] *= ratio``), clamped to [0, 1]
    unless ``clamp`` is False (``eval.protocol.apply_albedo_scale``)."""
    return [torch.where(m[..., None], apply_albedo_scale(p, s, space, clamp), p)
            for p, s, m in zip(pred, scales, masks)]


def relit_scale(out_linear: Tensor, ref_linear: Tensor, mask: Tensor) -> Tensor:
    """Per-channel least-squares scale of the relit prediction over masked pixels [3]
    (Stanford-ORB `calc_PSNR(scale_invariant=True)`)."""
    p, g = out_linear.double()[mask], ref_linear.double().clamp_min(0.0)[mask]
    den = (p * p).sum(0)
    return torch.where(den > SCALE_EPS, (p * g).sum(0) / den.clamp_min(1e-30),
                       torch.ones(3, dtype=torch.float64, device=den.device))


def relit_pair(out_linear: Tensor, ref_linear: Tensor, mask: Tensor, relight_cfg) -> RelitPair:
    """The protocol's relighting steps on one relit prediction: scale fit, then display."""
    if relight_cfg.scale_fit == "lstsq":
        out_linear = out_linear.double() * relit_scale(out_linear, ref_linear, mask)
        ref_linear = ref_linear.double()
    # tone-mapped in the shader's dtype (float32) as protocol v1 did: same numbers bit for bit
    return RelitPair(pred=display_relit(out_linear, relight_cfg), gt=display_relit(ref_linear, relight_cfg),
                     pred_linear=out_linear, gt_linear=ref_linear)


def relit_gt_image(scene: Scene, view, env_name: str, g: dict, env, reference: str = "shaded") -> Tensor:
    """The relit ground truth of one view [H, W, 3] linear: the split-sum of the GT maps
    (``eval.relight.reference: shaded`` on a scene whose ``relit_gt`` is ``shaded``), else the
    view's stored ``relit_<env>.exr`` (``reference: stored``, e.g. path-traced GT; or a dataset
    whose relit GT exists only as images), which needs the ``view``."""
    if reference == "shaded" and scene.relit_gt == "shaded":
        return relight_view(g["albedo"], g["roughness"], g["metallic"], g["normal"], g["view_dir"], env)
    if view is None:
        raise ValueError(f"{scene.root}: the stored relit ground truth needs the view")
    return load_stored_relit(scene, view, [env_name], g["view_dir"].device)[env_name]


def relit_pairs(scene: Scene, g: dict, p: dict, raw_albedo: Tensor, scale: Tensor, mask: Tensor, protocol,
                envs: EnvironmentCache, view=None) -> dict[str, RelitPair]:
    """env -> RelitPair of one view (GT normals; unmodelled channels filled with constants).
    ``scale``: the view's albedo alignment scale (for ``relight.clamp_albedo: false``).
    ``view``: the scene's View (its own relit environments, where the relit GT is read)."""
    cfg = protocol.relight
    h, w = mask.shape
    albedo, albedo_linear = (p["albedo"] if cfg.apply_albedo_alignment else raw_albedo), None
    if cfg.apply_albedo_alignment and not cfg.clamp_albedo:
        albedo_linear = unclamped_linear_albedo(raw_albedo, scale, protocol.alignment_space).to(raw_albedo.dtype)
    fill = dict(device=mask.device)
    rough = p.get("roughness", torch.full((h, w, 1), float(cfg.fill_roughness), **fill))
    metal = p.get("metallic", torch.full((h, w, 1), float(cfg.fill_metallic), **fill))
    out = {}
    for env_name in (cfg.envs or (scene.relight_envs if view is None else scene.view_relight_envs(view))):
        env = envs.get(scene.envmap_path(env_name))
        ref = relit_gt_image(scene, view, env_name, g, env, cfg.reference)
        pred = relight_view(albedo, rough, metal, g["normal"], g["view_dir"], env, albedo_linear=albedo_linear)
        out[env_name] = relit_pair(pred, ref, mask, cfg)
    return out


def view_albedo_scales(scene: Scene, all_views: list, have: list[str], preds: dict, gt: dict, masks: dict,
                       protocol) -> dict[str, Tensor]:
    """view id -> albedo alignment scale [3], for the views ``have`` with a predicted albedo.
    Fitted on the views whose ground truth has albedo; a view without GT albedo (an imported
    dataset's relighting view) takes the scene's pooled scale (``alignment_scope: scene``) or
    none (scope ``view``: refused when its relit image would use the aligned albedo)."""
    fit = [i for i in have if "albedo" in gt[i]]
    fitted = albedo_scales([preds[i]["albedo"] for i in fit], [gt[i]["albedo"] for i in fit], [masks[i] for i in fit],
                           protocol.albedo_alignment, protocol.alignment_scope, **protocol_alignment(protocol))
    scales = dict(zip(fit, fitted))
    rest = [i for i in have if i not in scales]
    if not rest:
        return scales
    if protocol.alignment_scope == "scene" and fitted:
        return {**scales, **{i: fitted[0] for i in rest}}
    unaligned = torch.ones(3, dtype=torch.float64, device=masks[rest[0]].device)
    needs = protocol.albedo_alignment != "none" and protocol.relight.apply_albedo_alignment and \
        "relight" in protocol.channels
    if needs:
        raise LayoutError(f"{scene.root / 'scene.json'}: view {rest[0]} has no albedo ground truth to align "
                          f"its relit albedo on (eval.albedo_alignment={protocol.albedo_alignment}, "
                          f"alignment_scope={protocol.alignment_scope}); set eval.relight.apply_albedo_alignment=false")
    return {**scales, **{i: unaligned for i in rest}}


def scene_scored_views(scene: Scene, pred_scene: Path, protocol, envs: EnvironmentCache,
                       views: Optional[list] = None, gt_cache: Optional[dict] = None
                       ) -> tuple[list[ScoredView], list[dict]]:
    """Every view of the scored split (or ``views`` of it) as scored; and the missing
    (view, channel) entries. Alignment always pools over ALL the split's views (scene scope),
    whichever views are returned. ``gt_cache``: a dict the caller keeps to read each GT view
    once across several predictions of the scene (the report's jobs)."""
    split = scored_split(protocol)
    # a view whose ground truth has no channel (scene.json gt_channels: [], e.g. a glTF import's
    # held-out view that sees nothing of a single-sided asset) has nothing to score
    all_views = [v for v in scene.split_views(split) if scene.view_gt_channels(v)]
    cache = {} if gt_cache is None else gt_cache
    for v in all_views:
        if (scene.name, split, v.id) not in cache:
            cache[(scene.name, split, v.id)] = load_gt_view(scene, v, envs.device)
    gt = {v.id: cache[(scene.name, split, v.id)] for v in all_views}
    if protocol.outside_brdf == "exclude":  # a view entirely outside the BRDF has nothing left
        all_views = [v for v in all_views if not wholly_outside_brdf(gt[v.id])]
    masks = {v.id: scored_mask(f"{scene.name}/{v.split}/{v.id}", gt[v.id]["mask"], protocol,
                               gt[v.id].get("outside_brdf")) for v in all_views}
    preds, divided = {}, set()
    for v in all_views:
        pdir = Path(pred_scene) / split / v.id
        preds[v.id] = load_pred_view(pdir, (scene.height, scene.width), envs.device) if pdir.is_dir() else {}
        alpha = preds[v.id].pop("alpha", None)
        if getattr(protocol, "unpremultiply", False) and alpha is not None:
            preds[v.id].update(unpremultiply(preds[v.id], alpha, masks[v.id]))
            divided.add(v.id)
    modelled = [c for c in MATERIAL_CHANNELS if any(c in p for p in preds.values())]
    missing = [{"scene": scene.name, "view": v.id, "channel": c}
               for v in all_views for c in modelled if c not in preds[v.id]]
    have = [v.id for v in all_views if "albedo" in preds[v.id]]
    scales = view_albedo_scales(scene, all_views, have, preds, gt, masks, protocol)
    albedos, have_masks = [preds[i]["albedo"] for i in have], [masks[i] for i in have]
    aligned = dict(zip(have, apply_scales(albedos, [scales[i] for i in have], have_masks,
                                          space=protocol.alignment_space, clamp=bool(protocol.albedo_clamp))))
    ids = None if views is None else {v.id for v in views}  # views of another split are not scored
    wanted = [v for v in all_views if ids is None or v.id in ids]
    out = []
    for v in wanted:
        p = dict(preds[v.id])
        relit = {}
        if v.id in aligned:
            raw, p["albedo"] = p["albedo"], aligned[v.id]
            if "relight" in protocol.channels and all(c in p for c in modelled) and \
                    "relight" in scene.view_gt_channels(v):
                relit = relit_pairs(scene, gt[v.id], p, raw, scales[v.id], masks[v.id], protocol, envs, v)
        out.append(ScoredView(scene=scene.name, view=v.id, mask=masks[v.id], gt=gt[v.id], pred=p, relit=relit,
                              unpremultiplied=v.id in divided))
    return out, missing

"""Stage II training data (paper Sec. "Training vs. Inference Dynamics").

Per scene, ``gt_points.npz`` (the unprojection of the 32 lattice views' GT depth,
``gspi.data.point_clouds``) gives every point its world position, source view k, source pixel,
linear RGB and PBR ground truth. From it:

* **Perturbation** (sub-pixel depth noise of Gaussian primitives): each point moves along the
  ray of its source view by ``delta ~ N(0, (k * footprint)^2)``, ``footprint = z / f_x`` = the
  width of one pixel at the point's camera depth z (``stage2.data.perturb_pixels`` = k, 0.5).
  Moving along the source ray keeps the point on its source pixel: the Top-RGB binding
  survives the noise exactly as the paper's hard binding intends.
* **Local subset** of ``num_points`` (N_train = 512): a uniformly random centre point and its
  N nearest neighbours (scipy ``cKDTree`` on the unperturbed cloud; the subset is perturbed
  afterwards, which is the same distribution as perturbing the whole cloud first).
  ``stage2.data.subset=whole`` (issue 52's named departure, not the paper) draws the N points
  uniformly from the whole object instead: every item shows all of the object's parts at once, as
  inference does (the whole cloud through the same latents), at a sparser density.
* **Coordinates**: the unit-sphere frame (``normalize.fit_unit_sphere``) of the whole
  unperturbed scene cloud, shared by all its subsets.
* **Local condition** (``stage2.data.local_condition``):
  ``top_rgb_onehot`` (default, 35) = [Top-RGB 3 || one-hot(source view) 32], with
  Top-RGB = ``linear_to_srgb(clamp(rgb_linear, 0, 1))`` in [0, 1], the transform Stage I
  applies at inference; ``top_rgb`` (A2, 3) = Top-RGB only; ``multiview`` (A5, 128) = for each
  of the 32 lattice views, the sRGB colour at the point's projection (nearest pixel, 0 outside
  the image) and a visibility flag (inside, foreground, ``|z - depth_gt| < tol * footprint``).
* **Pixel-aligned prior feature** (``stage2.data.pixel_features``, issue 42's named departure;
  off in the paper's recipe): the prior encoder's unpooled map of the point's source view
  (``encode_map``: [D, 13, 13] for AlexNet at 224 px), sampled bilinearly at the source pixel,
  appended to the local condition (+D). It tells each point what the encoder sees around its
  own pixel, which the 5 x 5 global cells leave to the attention to find.
* **Its spread over views** (``stage2.data.pixel_feature_spread``, issue 42's named departure,
  session 21): per channel, the standard deviation of that map sampled at the point's pixel in
  every lattice view that sees it (A5's depth test), appended (+D). A matte surface looks alike
  from every view, a mirror-like one does not.
* **Cross-view radiance** (``stage2.data.cross_view_radiance``, issue 52's named departure): per
  point, over the lattice views that see it (A5's depth test), the brightest view's luminance
  minus the median, the luminance's spread and the highlight's tint (``gspi.stage2.view_statistics``,
  5 values), read from the linear lattice images: what a glossy or metal surface shows and a
  single view cannot tell.
* **Its neighbourhood means** (``stage2.data.cross_view_neighbourhood``, issue 52's named departure,
  session 26): the means of that statistic and of Top-RGB over each point's 32 and 256 nearest
  points of a seeded 3000-point subset of the object (``view_statistics.neighbourhood_condition``,
  +16; a point outside the subset takes its nearest subset point's), computed once per scene on
  the unperturbed GT cloud: a point that shows no highlight itself takes its part's.
* **The light read-out** (``stage2.data.light_readout``, issue 66's named departure): each point's
  material read against the capture light, pooled over its neighbours, and how well it fits
  (``gspi.stage2.light_condition``, +7): in training the scene's own light (a share
  ``light_wrong_share`` of scenes told a wrong one), at inference and in the measure the light
  estimated among ``light_candidates``.
* **Targets** f0 = ``pbr_to_model([albedo (sRGB-encoded, as stored), roughness, metallic])`` in [-1, 1].
* **Global prior**: the scene's cached [32, D, 5, 5] encoder features as [32, 25, D] tokens;
  view-dropout keeps ``train_views`` (16) random views per item, with their lattice ids.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping, Optional

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from gspi.stage2.inputs import Stage2Inputs
from gspi.stage2.lattice_cameras import LatticeCameras, pixel_footprint, project_to_views  # noqa: F401 (re-exported)
from gspi.data.lattice import NUM_LATTICE_VIEWS
from gspi.stage2.light_condition import LIGHT_GEOMETRY, LIGHT_READOUT_WIDTH
from gspi.stage2.view_statistics import FIELDS as RADIANCE_FIELDS, NEIGHBOURHOOD_WIDTH, neighbourhood_lookup, \
    neighbourhood_table, radiance_condition
from gspi.stage2.normalize import SphereFrame, fit_unit_sphere, pbr_to_model, to_unit_sphere, view_onehot

LOCAL_CONDITIONS = {"top_rgb_onehot": 35, "top_rgb": 3, "multiview": 128}  # name -> width


def local_condition_dim(name: str) -> int:
    if name not in LOCAL_CONDITIONS:
        raise ValueError(f"unknown stage2.data.local_condition {name!r}; allowed: {sorted(LOCAL_CONDITIONS)}")
    return LOCAL_CONDITIONS[name]


def srgb_top_rgb(rgb_linear: np.ndarray) -> np.ndarray:
    """[..., 3] linear HDR -> [..., 3] float32 ``linear_to_srgb(clamp(x, 0, 1))`` (Top-RGB)."""
    from eval.common.colorspace import linear_to_srgb

    return linear_to_srgb(torch.from_numpy(np.asarray(rgb_linear, dtype=np.float32))).numpy()


def read_lattice_views(scene_dir: str | Path, *, depth: bool = True
                       ) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """(linear radiance [V, H, W, 3] float32, GT depth [V, H, W] float32 or None) of a scene
    folder's lattice views (its train split: ``rgb.exr``, ``depth.exr``), in the split's order."""
    from eval.common.layout import read_scene, read_view_file

    scene = read_scene(scene_dir)
    dirs = [scene.view_dir("train", v.id) for v in scene.split_views("train")]
    rgb = np.stack([read_view_file(d, "rgb.exr") for d in dirs]).astype(np.float32)
    if not depth:
        return rgb, None
    return rgb, np.stack([read_view_file(d, "depth.exr")[..., 0] for d in dirs]).astype(np.float32)


def read_lattice_cameras(scene_dir: str | Path):
    """(Scene, LatticeCameras) of a canonical scene folder; the train split must be the 32-view lattice."""
    from eval.common.layout import read_scene

    scene = read_scene(scene_dir)
    views = scene.split_views("train")
    if len(views) != NUM_LATTICE_VIEWS:
        raise ValueError(f"{Path(scene_dir) / 'scene.json'}: train split has {len(views)} views, "
                         f"Stage II needs the {NUM_LATTICE_VIEWS}-view lattice")
    cams = LatticeCameras(K=np.stack([v.K for v in views]), w2c=np.stack([v.w2c for v in views]),
                          width=scene.width, height=scene.height)
    return scene, cams


@dataclass
class ScenePoints:
    """One scene's GT point cloud with everything Stage II derives from it."""

    name: str
    xyz: np.ndarray  # [P, 3] float64 world, unperturbed
    view: np.ndarray  # [P] int64 source lattice view
    pixel: np.ndarray  # [P, 2] int64 (row, col) source pixel
    top_rgb: np.ndarray  # [P, 3] float32 sRGB in [0, 1]
    f0: np.ndarray  # [P, 5] float32 PBR targets in [-1, 1]
    frame: SphereFrame  # unit-sphere frame of the unperturbed cloud
    cameras: LatticeCameras
    global_tokens: Optional[Tensor]  # [32, 25, D] or None (no prior)
    root: Path
    feature_maps: Optional[Tensor] = field(default=None, repr=False)  # [32, D, g, g] (pixel_features)
    _tree: Optional[cKDTree] = field(default=None, repr=False)
    _views: Optional[tuple[np.ndarray, np.ndarray]] = field(default=None, repr=False)
    _linear: Optional[np.ndarray] = field(default=None, repr=False)
    _neighbourhood: Optional[tuple[np.ndarray, np.ndarray]] = field(default=None, repr=False)
    light_source: str = "capture"  # the light the read-out is told: capture (training) | estimated (measure)
    told_light: str = "estimated"  # with estimated: the estimate, or deliberately wrong (points_measure.told_light)
    _light: Optional[tuple[np.ndarray, np.ndarray]] = field(default=None, repr=False)
    light_info: Optional[dict] = None  # which light the read-out was told (after light_features)
    light_cache: Optional[Path] = None  # where its read-out table is kept between processes (light_table_cache)

    @property
    def num_points(self) -> int:
        return len(self.xyz)

    def prior_grid(self) -> Optional[Tensor]:
        """The global prior as the sampler takes it: [32, D, 5, 5] (None without a prior)."""
        if self.global_tokens is None:
            return None
        return self.global_tokens.transpose(1, 2).unflatten(2, (5, 5))

    @property
    def tree(self) -> cKDTree:
        if self._tree is None:
            self._tree = cKDTree(self.xyz)
        return self._tree

    def lattice_views(self) -> tuple[np.ndarray, np.ndarray]:
        """(sRGB images [V, H, W, 3] float32, GT depth [V, H, W] float32), loaded once (A5)."""
        if self._views is None:
            rgb, depth = read_lattice_views(self.root)
            self._views = (srgb_top_rgb(rgb), depth)
        return self._views

    def lattice_linear(self) -> np.ndarray:
        """[V, H, W, 3] float32 linear radiance of the lattice views (``rgb.exr``), loaded once."""
        if self._linear is None:
            self._linear = read_lattice_views(self.root, depth=False)[0]
        return self._linear

    def neighbourhood_features(self, idx: np.ndarray, tol_pixels: float = 2.0) -> np.ndarray:
        """[n, 16] ``stage2.data.cross_view_neighbourhood`` of points ``idx`` of the unperturbed cloud
        (``view_statistics.neighbourhood_condition``; its subset's table computed once per scene)."""
        if self._neighbourhood is None:
            _, depth = self.lattice_views()
            self._neighbourhood = neighbourhood_table(self.lattice_linear(), depth, self.cameras, self.xyz,
                                                      self.top_rgb, tol_pixels=tol_pixels)
        return neighbourhood_lookup(self._neighbourhood, self.xyz[idx])


    def light_features(self, idx: np.ndarray, cfg: "PointDataConfig") -> np.ndarray:
        """[n, LIGHT_READOUT_WIDTH] ``stage2.data.light_readout`` of points ``idx`` of the
        unperturbed cloud (its subset's table computed once per scene)."""
        from gspi.stage2 import light_condition as lc

        if self._light is None:
            self._light = self._cached_light_table(cfg)
        return lc.readout_lookup(self._light, self.xyz[idx])

    def _cached_light_table(self, cfg: "PointDataConfig") -> tuple[np.ndarray, np.ndarray]:
        """The read-out table from ``light_cache`` where it holds this scene's under this config and
        light (``light_table_cache``), else read and kept there."""
        from gspi.stage2 import light_table_cache as cache
        from gspi.stage2.light_condition import photo_source

        path = None
        if self.light_cache is not None:
            key = cache.table_key(cfg, self.light_source, self.told_light, self.name,
                                  [self.root, photo_source(self.root)])
            path = cache.table_path(self.light_cache, self.name, key)
            hit = cache.load_table(path)
            if hit is not None:
                table, self.light_info = hit
                return table
        table = self._light_table(cfg)
        if path is not None:
            cache.save_table(path, table, self.light_info)
        return table

    def _light_table(self, cfg: "PointDataConfig") -> tuple[np.ndarray, np.ndarray]:
        """(subset xyz, rows) of the read-out: this scene read against the light it is told."""
        from gspi.stage2 import light_condition as lc

        if cfg.light_geometry == "asset":  # as a run reads it: Stage I's cloud of the asset, the photos
            seen = lc.asset_views(self.root)
            rgb, depth, cams, xyz = seen.images, seen.depth, seen.cams, seen.xyz
            normals = lc.cloud_normals_of(seen.xyz, seen.view, seen.cams)
        else:
            rgb, depth, cams, xyz = self.lattice_linear(), self.lattice_views()[1], self.cameras, self.xyz
            normals = lc.cloud_normals_of(self.xyz, self.view, self.cameras)
        light = self._told_light(cfg, rgb, depth, cams, xyz, normals)
        return lc.readout_table(rgb, depth, cams, xyz, normals, light, tol_pixels=cfg.visibility_tol_pixels,
                                normal_search_deg=cfg.light_normal_search_deg, normal_profile=cfg.light_normal_profile,
                                metal_min_evidence=cfg.light_metal_min_evidence)

    def _told_light(self, cfg: "PointDataConfig", rgb: np.ndarray, depth: np.ndarray, cams: LatticeCameras,
                    xyz: np.ndarray, normals):
        from eval.common.layout import read_scene
        from gspi.stage2 import light_condition as lc
        from gspi.stage2.light_condition import candidate_lights, capture_light

        if self.light_source == "estimated":
            candidates = candidate_lights(cfg.light_candidates, cfg.light_env_height)
            light, est = lc.estimate_scene_light(rgb, depth, cams, xyz, normals, candidates,
                                                 tol_pixels=cfg.visibility_tol_pixels)
            told = lc.mistold_light(light, candidates, self.name, self.told_light)
            self.light_info = {"env": est.env, "rotation_deg": float(est.rotation_deg), "gain": float(est.gain),
                               "margin": float(est.margin),
                               **({} if told is light else {"told": {"how": self.told_light, "env": told.env,
                                                                      "rotation_deg": float(told.rotation_deg)}})}
            return told
        scene = read_scene(self.root)
        capture = capture_light(scene.envmap_path(scene.capture_env), cfg.light_env_height)
        others = {name: (lambda name=name: candidate_lights([name], cfg.light_env_height)[name])
                  for name in candidate_lights_names(cfg.light_candidates)}
        light = lc.training_light(self.name, scene.capture_env, capture, others, cfg.light_wrong_share)
        self.light_info = {"env": light.env, "rotation_deg": light.rotation_deg, "wrong": light.wrong}
        return light


def candidate_lights_names(spec) -> list[str]:
    from gspi.data.env_sets import resolve_env_set

    return sorted(resolve_env_set(list(spec) if isinstance(spec, tuple) else spec, "capture"))


def load_scene_points(scene_dir: str | Path, global_features: Optional[Tensor],
                      feature_maps: Optional[Tensor] = None) -> ScenePoints:
    """Reads ``<scene_dir>/gt_points.npz`` and the lattice cameras.

    Args:
        global_features: [32, D, 5, 5] prior features (``feature_cache.scene_prior_features``)
            or None / D = 0 for no prior.
        feature_maps: [32, D, g, g] unpooled maps (``feature_cache.scene_feature_maps``) for
            ``stage2.data.pixel_features``, else None.
    """
    scene_dir = Path(scene_dir)
    path = scene_dir / "gt_points.npz"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing (generate the dataset with point_clouds: true)")
    with np.load(path) as npz:
        pts = {k: npz[k] for k in npz.files}
    _, cams = read_lattice_cameras(scene_dir)
    xyz = pts["xyz"].astype(np.float64)
    pbr = np.concatenate([pts["albedo"], pts["roughness"][:, None], pts["metallic"][:, None]], axis=1)
    tokens = None
    if global_features is not None and global_features.shape[1] > 0:
        tokens = global_features.flatten(2).transpose(1, 2).contiguous().float()  # [32, 25, D], cell = 5 r + c
    return ScenePoints(
        name=scene_dir.name, xyz=xyz, view=pts["view"].astype(np.int64), pixel=pts["pixel"].astype(np.int64),
        top_rgb=srgb_top_rgb(pts["rgb"]), f0=pbr_to_model(torch.from_numpy(pbr.astype(np.float32))).numpy(),
        frame=fit_unit_sphere(torch.from_numpy(xyz)), cameras=cams, global_tokens=tokens, root=scene_dir,
        feature_maps=feature_maps)


def perturb_along_rays(xyz: np.ndarray, views: np.ndarray, cameras: LatticeCameras, *,
                       sigma_pixels: float, rng: np.random.Generator) -> np.ndarray:
    """Moves points [n, 3] along their source-view rays by N(0, (sigma_pixels * footprint)^2)."""
    if sigma_pixels == 0:
        return xyz.copy()
    centres = cameras.centers[views]
    offset = xyz - centres
    dist = np.linalg.norm(offset, axis=-1, keepdims=True)
    z = np.einsum("ni,ni->n", offset, cameras.w2c[views, 2, :3])
    delta = rng.standard_normal(len(xyz)) * sigma_pixels * pixel_footprint(z, cameras, views)
    return xyz + offset / dist * delta[:, None]


def local_subset(scene: ScenePoints, num_points: int, rng: np.random.Generator) -> np.ndarray:
    """[num_points] indices: a random centre point and its nearest neighbours (all if fewer)."""
    if num_points >= scene.num_points:
        return np.arange(scene.num_points)
    centre = scene.xyz[rng.integers(scene.num_points)]
    _, idx = scene.tree.query(centre, k=num_points)
    return np.asarray(idx, dtype=np.int64)


def whole_object_subset(scene: ScenePoints, num_points: int, rng: np.random.Generator) -> np.ndarray:
    """[num_points] indices drawn uniformly without replacement from the whole object (all if fewer)."""
    if num_points >= scene.num_points:
        return np.arange(scene.num_points)
    return np.sort(rng.choice(scene.num_points, num_points, replace=False))


SUBSETS = {"local": local_subset, "whole": whole_object_subset}  # stage2.data.subset -> item sampler


def multiview_condition(scene: ScenePoints, xyz: np.ndarray, *, tol_pixels: float,
                        chunk: int = 65536) -> np.ndarray:
    """A5 condition [n, 32 * 4]: per lattice view (view-major) sRGB at the projection + visibility."""
    images, depth = scene.lattice_views()
    return multiview_condition_from_views(images, depth, scene.cameras, xyz, tol_pixels=tol_pixels, chunk=chunk)


def multiview_condition_from_views(images: np.ndarray, depth: np.ndarray, cams: LatticeCameras, xyz: np.ndarray,
                                   *, tol_pixels: float, chunk: int = 65536) -> np.ndarray:
    """A5 condition [n, V * 4] from lattice images [V, H, W, 3] (sRGB) and depths [V, H, W].

    Per view: the colour at the point's projection (nearest pixel; 0 outside the image) and a
    visibility flag (``project_to_views``). Training passes the GT views and GT depth, inference
    (``gspi.stage2.infer``) the asset's renders.
    """
    num_views = len(images)
    out = np.zeros((len(xyz), num_views, 4), dtype=np.float32)
    views = np.arange(num_views)[:, None]
    for s in range(0, len(xyz), chunk):
        row, col, inside, visible = project_to_views(cams, depth, xyz[s:s + chunk], tol_pixels=tol_pixels)
        rgb = images[views, row, col] * inside[..., None]  # [V, n, 3]
        out[s:s + chunk] = np.concatenate([rgb, visible[..., None]], axis=-1).transpose(1, 0, 2)
    return out.reshape(len(xyz), num_views * 4)


def feature_spread_over_views(maps: Tensor, depth: np.ndarray, cams: LatticeCameras, xyz: np.ndarray, *,
                         tol_pixels: float, chunk: int = 4096) -> np.ndarray:
    """[n, D] float32: per channel, the standard deviation over the views that see each point
    (``project_to_views``) of the encoder maps [V, D, g, g] sampled at its pixel in each view
    (``sample_pixel_features``); 0 where fewer than two views see it. A matte surface looks
    alike from every view, a mirror-like one does not: the spread is what a single view cannot
    tell (``stage2.data.pixel_feature_spread``, issue 42)."""
    num_views, dim = maps.shape[:2]
    out = np.zeros((len(xyz), dim), dtype=np.float32)
    for s in range(0, len(xyz), chunk):
        row, col, _, visible = project_to_views(cams, depth, xyz[s:s + chunk], tol_pixels=tol_pixels)
        m = row.shape[1]
        v_idx, p_idx = np.nonzero(visible)  # only the (view, point) pairs that see each other
        feats = torch.from_numpy(sample_pixel_features(maps, v_idx, np.stack([row[v_idx, p_idx], col[v_idx, p_idx]], 1),
                                                       (cams.height, cams.width))).double()
        points = torch.from_numpy(p_idx)
        count = torch.bincount(points, minlength=m).double()[:, None]
        mean = torch.zeros(m, dim, dtype=torch.float64).index_add_(0, points, feats) / count.clamp(min=1)
        var = torch.zeros(m, dim, dtype=torch.float64).index_add_(0, points, (feats - mean[points]) ** 2)
        std = (var / count.clamp(min=1)).sqrt()
        out[s:s + chunk] = torch.where(count >= 2, std, torch.zeros(())).float().numpy()
    return out


def sample_pixel_features(maps: Tensor, view: np.ndarray, pixel: np.ndarray, image_size: tuple[int, int]
                          ) -> np.ndarray:
    """[n, D] float32: maps [V, D, g, g] of views ``view`` [n] sampled bilinearly at the centres of
    pixels ``pixel`` [n, 2] (row, col) of [H, W] images; the map covers the image (``align_corners
    = False``) and clamps at its border, as ``torch.nn.functional.grid_sample(..., padding_mode=
    "border")`` (the test's oracle; a gather of 4 cells per point instead of one grid_sample per view)."""
    height, width = image_size
    gh, gw = maps.shape[-2:]
    cells = maps.permute(0, 2, 3, 1)  # [V, g, g, D]
    view = torch.as_tensor(np.asarray(view, dtype=np.int64))
    pix = np.asarray(pixel, dtype=np.float64)
    y = np.clip((pix[:, 0] + 0.5) * gh / height - 0.5, 0.0, gh - 1)  # map coordinates of the centre
    x = np.clip((pix[:, 1] + 0.5) * gw / width - 0.5, 0.0, gw - 1)
    y0, x0 = np.floor(y).astype(np.int64), np.floor(x).astype(np.int64)
    y1, x1 = np.minimum(y0 + 1, gh - 1), np.minimum(x0 + 1, gw - 1)
    wy, wx = torch.from_numpy((y - y0)[:, None]).float(), torch.from_numpy((x - x0)[:, None]).float()
    y0, y1, x0, x1 = (torch.from_numpy(a) for a in (y0, y1, x0, x1))
    top = cells[view, y0, x0] * (1 - wx) + cells[view, y0, x1] * wx
    bottom = cells[view, y1, x0] * (1 - wx) + cells[view, y1, x1] * wx
    return (top * (1 - wy) + bottom * wy).float().numpy()


def local_condition(scene: ScenePoints, idx: np.ndarray, xyz_perturbed: np.ndarray, mode: str,
                    *, tol_pixels: float = 2.0, pixel_features: bool = False,
                    pixel_feature_spread: bool = False, cross_view_radiance: bool = False,
                    cross_view_neighbourhood: bool = False, light: Optional["PointDataConfig"] = None) -> np.ndarray:
    """[n, C] local condition of points ``idx`` (C = 35 / 3 / 128, + 5 with ``cross_view_radiance``,
    + 16 with ``cross_view_neighbourhood``, + 7 with ``light`` (a config whose ``light_readout``
    is on), + D with ``pixel_features``, + D with ``pixel_feature_spread``, in that order; see
    module docstring)."""
    local_condition_dim(mode)
    if mode == "top_rgb":
        cond = scene.top_rgb[idx]
    elif mode == "top_rgb_onehot":
        onehot = view_onehot(torch.from_numpy(scene.view[idx]), NUM_LATTICE_VIEWS).numpy()
        cond = np.concatenate([scene.top_rgb[idx], onehot], axis=1)
    else:
        cond = multiview_condition(scene, xyz_perturbed, tol_pixels=tol_pixels)
    if cross_view_radiance:
        _, depth = scene.lattice_views()
        cond = np.concatenate([cond, radiance_condition(scene.lattice_linear(), depth, scene.cameras, xyz_perturbed,
                                                        tol_pixels=tol_pixels)], axis=1)
    if cross_view_neighbourhood:
        cond = np.concatenate([cond, scene.neighbourhood_features(idx, tol_pixels)], axis=1)
    if light is not None and light.light_readout:
        cond = np.concatenate([cond, scene.light_features(idx, light)], axis=1)
    if not (pixel_features or pixel_feature_spread):
        return cond
    if scene.feature_maps is None:
        key = "pixel_features" if pixel_features else "pixel_feature_spread"
        raise ValueError(f"scene {scene.name}: stage2.data.{key} needs the prior encoder's maps "
                         "(gspi.stage2.splits.load_split loads them)")
    parts = [cond]
    if pixel_features:
        parts.append(sample_pixel_features(scene.feature_maps, scene.view[idx], scene.pixel[idx],
                                           (scene.cameras.height, scene.cameras.width)))
    if pixel_feature_spread:
        _, depth = scene.lattice_views()
        parts.append(feature_spread_over_views(scene.feature_maps, depth, scene.cameras, xyz_perturbed,
                                               tol_pixels=tol_pixels))
    return np.concatenate(parts, axis=1)


@dataclass(frozen=True)
class PointDataConfig:
    """``stage2.data``: how items are drawn from the GT point clouds."""

    num_points: int = 512  # N_train points per local subset (A3/A4: 1024)
    subset: str = "local"  # local: a point and its N nearest (paper) | whole: N points over the object (issue 52)
    perturb_pixels: float = 0.5  # depth-noise sigma in pixel footprints at the point's depth
    local_condition: str = "top_rgb_onehot"  # top_rgb_onehot (35) | top_rgb (A2, 3) | multiview (A5, 128)
    visibility_tol_pixels: float = 2.0  # A5 depth test tolerance, in pixel footprints
    train_views: int = 16  # view-dropout: global-prior views kept per training item
    pixel_features: bool = False  # + the prior's map at the source pixel (issue 42; not the paper)
    pixel_feature_spread: bool = False  # + its spread over the views that see the point (issue 42; not the paper)
    cross_view_radiance: bool = False  # + the point's radiance over the views that see it, 5 values (issue 52; not the paper)
    cross_view_neighbourhood: bool = False  # + its and Top-RGB's means over the point's neighbours, 16 (issue 52; not the paper)
    light_readout: bool = False  # + the point's material read against the light, 7 (issue 66; not the paper)
    light_wrong_share: float = 0.0  # training scenes told a wrong light (light_readout)
    light_candidates: Any = "procedural"  # lights estimated among at inference (gspi.data.env_sets)
    light_env_height: int = 64  # rows of the lights' lat-long maps
    light_geometry: str = "cloud"  # the read-out on the scene's cloud and lattice views | asset: on Stage I's cloud
                                   # of its Stage 0 asset, in its photos (as a run reads it; a reconstructed pool)
    light_normal_search_deg: Any = None  # the read-out's normal search, degrees (as method=light_fit's); None = none
    light_normal_profile: int = 1  # each grid cell the best of this many searched normals (method.normal_profile)
    light_metal_min_evidence: Any = None  # the read-out's scene-level metal test (method.metal_min_evidence); None = none

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any]) -> "PointDataConfig":
        out = cls(**dict(cfg))
        local_condition_dim(out.local_condition)
        if not 0.0 <= out.light_wrong_share <= 1.0:
            raise ValueError(f"stage2.data.light_wrong_share must lie in [0, 1], got {out.light_wrong_share}")
        if isinstance(out.light_candidates, list):
            out = replace(out, light_candidates=tuple(out.light_candidates))
        if out.light_normal_search_deg is not None:
            out = replace(out, light_normal_search_deg=tuple(float(d) for d in out.light_normal_search_deg))
        if out.light_metal_min_evidence is not None and not float(out.light_metal_min_evidence) >= 1.0:
            raise ValueError("stage2.data.light_metal_min_evidence is a ratio >= 1 (the metal evidence's floor) "
                             f"or null, got {out.light_metal_min_evidence}")
        if out.light_geometry not in LIGHT_GEOMETRY:
            raise ValueError(f"stage2.data.light_geometry must be one of {', '.join(LIGHT_GEOMETRY)}, "
                             f"got {out.light_geometry!r}")
        if out.subset not in SUBSETS:
            raise ValueError(f"stage2.data.subset must be one of {sorted(SUBSETS)}, got {out.subset!r}")
        return out

    def _width_before_light(self) -> int:
        """Width of the condition's columns that come before the light read-out (``local_condition``'s order)."""
        return (local_condition_dim(self.local_condition) + (len(RADIANCE_FIELDS) if self.cross_view_radiance else 0)
                + (NEIGHBOURHOOD_WIDTH if self.cross_view_neighbourhood else 0))

    def condition_width(self, feature_dim: int) -> int:
        """The local condition's width with an encoder of ``feature_dim`` channels."""
        return (self._width_before_light() + (LIGHT_READOUT_WIDTH if self.light_readout else 0)
                + (feature_dim if self.pixel_features else 0) + (feature_dim if self.pixel_feature_spread else 0))

    def light_readout_column(self) -> int:
        """Where the light read-out's columns start in the local condition."""
        if not self.light_readout:
            raise ValueError("stage2.diffusion.prediction=x0_readout corrects the light read-out: "
                             "it needs stage2.data.light_readout=true")
        return self._width_before_light()

    @property
    def needs_feature_maps(self) -> bool:
        """Whether the local condition samples the prior encoder's unpooled maps."""
        return self.pixel_features or self.pixel_feature_spread


def scene_item(scene: ScenePoints, idx: np.ndarray, cfg: PointDataConfig, rng: np.random.Generator
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xyz_unit [n, 3], local_cond [n, C], f0 [n, 5]) of points ``idx`` with a fresh perturbation."""
    xyz = perturb_along_rays(scene.xyz[idx], scene.view[idx], scene.cameras,
                             sigma_pixels=cfg.perturb_pixels, rng=rng)
    cond = local_condition(scene, idx, xyz, cfg.local_condition, tol_pixels=cfg.visibility_tol_pixels,
                           pixel_features=cfg.pixel_features, pixel_feature_spread=cfg.pixel_feature_spread,
                           cross_view_radiance=cfg.cross_view_radiance,
                           cross_view_neighbourhood=cfg.cross_view_neighbourhood, light=cfg)
    xyz_unit = to_unit_sphere(torch.from_numpy(xyz), scene.frame).numpy()
    return xyz_unit.astype(np.float32), cond.astype(np.float32), scene.f0[idx]


def sample_batch(scenes: list[ScenePoints], cfg: PointDataConfig, batch_size: int,
                 rng: np.random.Generator) -> tuple[Tensor, Stage2Inputs]:
    """One training batch: B items, each a subset (``cfg.subset``) of a uniformly drawn scene.

    Returns:
        f0 [B, N, 5] in [-1, 1] and Stage2Inputs (xyz [B, N, 3] unit sphere, local_cond
        [B, N, C], global_tokens [B, train_views, 25, D] + view_ids [B, train_views] or None).
    """
    xyz, cond, f0, tokens, view_ids = [], [], [], [], []
    for _ in range(batch_size):
        scene = scenes[int(rng.integers(len(scenes)))]
        idx = SUBSETS[cfg.subset](scene, cfg.num_points, rng)
        if len(idx) < cfg.num_points:
            raise ValueError(f"scene {scene.name} has {len(idx)} points < num_points {cfg.num_points}")
        x, c, f = scene_item(scene, idx, cfg, rng)
        xyz.append(x), cond.append(c), f0.append(f)
        if scene.global_tokens is not None:
            keep = np.sort(rng.permutation(len(scene.global_tokens))[:cfg.train_views])
            tokens.append(scene.global_tokens[keep])
            view_ids.append(torch.from_numpy(keep))
    inputs = Stage2Inputs(xyz=torch.from_numpy(np.stack(xyz)), local_cond=torch.from_numpy(np.stack(cond)),
                          global_tokens=torch.stack(tokens) if tokens else None,
                          view_ids=torch.stack(view_ids) if view_ids else None)
    return torch.from_numpy(np.stack(f0)), inputs


def whole_scene_inputs(scene: ScenePoints, cfg: PointDataConfig, rng: np.random.Generator
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Inference/evaluation inputs of ALL points: (perturbed xyz_world [P, 3], local_cond [P, C])."""
    idx = np.arange(scene.num_points)
    xyz = perturb_along_rays(scene.xyz, scene.view, scene.cameras, sigma_pixels=cfg.perturb_pixels, rng=rng)
    return xyz, local_condition(scene, idx, xyz, cfg.local_condition, tol_pixels=cfg.visibility_tol_pixels,
                                pixel_features=cfg.pixel_features, pixel_feature_spread=cfg.pixel_feature_spread,
                                cross_view_radiance=cfg.cross_view_radiance,
                                cross_view_neighbourhood=cfg.cross_view_neighbourhood, light=cfg)

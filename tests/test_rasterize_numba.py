"""The numba compositor (gspi/gaussians/numba_composite.py) against the torch reference.

Every output and every gradient of ``rasterize_view(composite="numba")`` must equal
``composite="torch"`` (``TileComposite``) within a fraction of the largest reference value:
1e-5 in float64 (measured <= 1.5e-13 over 24 random scenes), 2e-3 in float32 (measured
<= 7.7e-4: float32 rounding of the torch path, which is itself up to 3.8e-3 from the float64
result; the numba kernels compute in float64 inside and are never further from it). The
kernels compile once per dtype into numba's on-disk cache (~20 s cold, ~1 s warm here).
"""

from __future__ import annotations

import math

import numba
import pytest
import torch

from gspi.gaussians import numba_jit
from gspi.gaussians.numba_composite import composite_view
from gspi.gaussians.projection import project_surfels
from gspi.gaussians.rasterize import _resolve_backend, rasterize_2dgs, tile_backend
from gspi.gaussians.tiles import bin_splats, pixel_bounds
from gspi.gaussians.torch_backend import rasterize_view, surfel_table
from tests.raster_fixtures import random_scene

W, H = 64, 48  # non-square, and 48 is not a multiple of 16: partial tiles
TOL = {torch.float64: 1e-5, torch.float32: 2e-3}
NAMES = ("ray_transforms", "means2d", "depths", "opacities", "channels")


def _camera(width, height, dtype, focal=60.0):
    K = torch.tensor([[focal, 0.0, width / 2], [0.0, focal, height / 2], [0.0, 0.0, 1.0]], dtype=dtype)
    return torch.eye(4, dtype=dtype)[None], K[None]


def view_inputs(n, seed, dtype=torch.float64, width=W, height=H, scales=None, spread=0.6):
    """Leaf tensors (requiring grad) for ``rasterize_view`` of a random scene, and the in-range mask."""
    means, quats, sc, opacities, colors = random_scene(n, seed, dtype=dtype, spread=spread)
    if scales is not None:
        sc = scales
    vm, K = _camera(width, height, dtype)
    proj = project_surfels(means, quats, sc, vm, K, width, height, 0.01, 1e10)
    chans = torch.cat([colors, proj.normals[0]], -1)
    leaves = [t.detach().clone().requires_grad_() for t in
              (proj.ray_transforms[0], proj.means2d[0], proj.depths[0], opacities, chans)]
    in_range = proj.depths[0].detach() > 0.01
    return leaves, in_range


def render_both(leaves, in_range, width=W, height=H, seed=0, **kw):
    """{composite: (image, gradients of a random linear loss w.r.t. the leaves)}."""
    gen = torch.Generator().manual_seed(seed)
    weights = None
    result = {}
    for composite in ("torch", "numba"):
        img = rasterize_view(*leaves, in_range, width, height, composite=composite, **kw)
        if weights is None:
            weights = torch.randn(img.shape, generator=gen, dtype=img.dtype)
        grads = torch.autograd.grad((img * weights).sum(), leaves, allow_unused=True)
        result[composite] = (img.detach(), [torch.zeros_like(x) if g is None else g for g, x in zip(grads, leaves)])
    return result


def assert_rel(actual, expected, tol, what):
    actual, expected = actual.detach(), expected.detach()
    scale = max(float(expected.abs().max()), 1e-30) if expected.numel() else 1.0
    err = float((actual - expected).abs().max()) if expected.numel() else 0.0
    assert err <= tol * scale, f"{what}: max |numba - torch| = {err:.3g}, {err / scale:.3g} of max |torch| {scale:.3g}"


def assert_same(result, tol):
    (img_t, grads_t), (img_n, grads_n) = result["torch"], result["numba"]
    assert img_n.shape == img_t.shape and img_n.dtype == img_t.dtype
    names = [f"channel {i}" for i in range(img_t.shape[-1] - 3)] + ["alpha", "sum w z", "median depth"]
    for c, name in enumerate(names):
        assert_rel(img_n[..., c], img_t[..., c], tol, name)
    for g_n, g_t, name in zip(grads_n, grads_t, NAMES):
        assert_rel(g_n, g_t, tol, "d/d " + name)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("tile_size", [8, 16])
@pytest.mark.parametrize("intersection", [True, False])
def test_matches_torch_float64(seed, tile_size, intersection):
    leaves, in_range = view_inputs(300, seed)
    result = render_both(leaves, in_range, seed=seed, tile_size=tile_size, intersection_depth=intersection)
    assert float(result["torch"][0][..., -3].max()) > 0.5  # the scene covers the image
    assert_same(result, TOL[torch.float64])


@pytest.mark.parametrize("seed", [0, 3])
@pytest.mark.parametrize("tile_size", [8, 16])
def test_matches_torch_float32(seed, tile_size):
    leaves, in_range = view_inputs(300, seed, dtype=torch.float32)
    assert_same(render_both(leaves, in_range, seed=seed, tile_size=tile_size), TOL[torch.float32])


def test_float32_no_further_from_float64_than_torch():
    leaves, in_range = view_inputs(300, 1, dtype=torch.float32)
    truth = render_both([x.detach().double().requires_grad_() for x in leaves], in_range, seed=1)["torch"]
    both = render_both(leaves, in_range, seed=1)
    for name, got_t, got_n, ref in zip(("image",) + NAMES, [both["torch"][0], *both["torch"][1]],
                                       [both["numba"][0], *both["numba"][1]], [truth[0], *truth[1]]):
        err_t, err_n = ((got.double() - ref).abs().max() for got in (got_t, got_n))
        assert err_n <= 1.5 * err_t + 1e-6 * ref.abs().max(), name


def test_early_termination_in_opaque_stacks():
    """Near-opaque surfels: many pixels stop at T <= 1e-4 (gsplat's early termination)."""
    leaves, in_range = view_inputs(400, 14, spread=0.25)
    with torch.no_grad():
        leaves[3].uniform_(0.9, 0.999)
    result = render_both(leaves, in_range)
    assert float((result["torch"][0][..., -3] > 0.999).float().mean()) > 0.05  # ~11 % of the pixels
    assert_same(result, TOL[torch.float64])


def test_long_lists_walked_in_segments_by_torch():
    """A small max_elems makes the torch path split lists and carry T; numba walks them whole."""
    leaves, in_range = view_inputs(400, 4)
    assert_same(render_both(leaves, in_range, max_elems=4096), TOL[torch.float64])


def test_behind_camera_and_out_of_range_get_no_gradient():
    leaves, in_range = view_inputs(200, 5)
    in_range[10:60] = False  # as if beyond the far plane
    result = render_both(leaves, in_range)
    assert_same(result, TOL[torch.float64])
    behind = (leaves[2].detach() <= 0.01) | ~in_range
    assert behind[0] and behind[10:60].all()  # random_scene puts surfel 0 behind the camera
    for g in result["numba"][1]:
        assert (g[behind] == 0).all()


def test_degenerate_scales():
    scales = random_scene(150, 6)[2].clone()
    scales[::3] = 1e-9  # sub-pixel: only the screen-space filter shows
    scales[1::3, 1] = 1e-12  # needles: the ray is (nearly) parallel to the splat plane
    leaves, in_range = view_inputs(150, 6, scales=scales)
    assert_same(render_both(leaves, in_range), TOL[torch.float64])


def test_empty_tiles():
    leaves, in_range = view_inputs(120, 7)
    in_range &= leaves[1].detach()[:, 0] < 20  # only surfels centred in the left third
    result = render_both(leaves, in_range)
    assert (result["numba"][0][:, 40:] == 0).all()  # mostly empty tiles on the right
    assert_same(result, TOL[torch.float64])


def test_all_empty_image_backward_is_zero():
    leaves, in_range = view_inputs(50, 8)
    result = render_both(leaves, torch.zeros_like(in_range))
    assert (result["numba"][0] == 0).all()
    assert all((g == 0).all() for g in result["numba"][1])
    assert_same(result, TOL[torch.float64])


def test_single_pixel_image():
    leaves, in_range = view_inputs(300, 9, width=1, height=1)
    result = render_both(leaves, in_range, width=1, height=1)
    assert result["numba"][0].shape[:2] == (1, 1)
    assert_same(result, TOL[torch.float64])


def test_several_views_through_rasterize_2dgs():
    """rasterize_2dgs with three cameras, SH colours and features: leaf gradients equal."""
    means, quats, scales, opacities, _ = random_scene(120, 10)
    gen = torch.Generator().manual_seed(10)
    sh = 0.3 * torch.randn(120, 16, 3, generator=gen, dtype=torch.float64)
    feats = torch.rand(120, 5, generator=gen, dtype=torch.float64)
    leaves = [t.clone().requires_grad_() for t in (means, quats, scales, opacities, sh, feats)]
    angles = torch.tensor([0.0, 0.15, -0.2], dtype=torch.float64)
    vms = torch.eye(4, dtype=torch.float64).repeat(3, 1, 1)
    vms[:, 0, 0], vms[:, 0, 2], vms[:, 2, 0], vms[:, 2, 2] = angles.cos(), angles.sin(), -angles.sin(), angles.cos()
    Ks = _camera(40, 24, torch.float64, focal=40.0)[1].repeat(3, 1, 1)
    grads, outs = {}, {}
    for backend in ("torch", "numba"):
        out = rasterize_2dgs(*leaves[:5], vms, Ks, 40, 24, features=leaves[5], sh_degree=3, backend=backend,
                             backgrounds=torch.ones(3, 3, dtype=torch.float64))
        loss = sum(((i + 1) * t).sum() for i, t in enumerate(
            (out.rgb, out.features, out.alpha, out.depth_expected, out.depth_median, out.normals)))
        grads[backend] = torch.autograd.grad(loss, leaves)
        outs[backend] = out
    for key in ("rgb", "features", "alpha", "depth_expected", "depth_median", "normals"):
        assert_rel(getattr(outs["numba"], key), getattr(outs["torch"], key), 1e-5, key)
    for g_n, g_t, name in zip(grads["numba"], grads["torch"], ("means", "quats", "scales", "opacities", "sh", "feats")):
        assert_rel(g_n, g_t, 1e-5, "d/d " + name)


def test_gradcheck_tiny_scene():
    """Finite differences of the compiled function itself (few smooth surfels, 12 x 10 px)."""
    leaves, in_range = view_inputs(6, 11, width=12, height=10)
    table = surfel_table(*[x.detach() for x in leaves]).requires_grad_()
    lo, hi, valid = pixel_bounds(leaves[0].detach(), leaves[1].detach(), leaves[3].detach(), 12, 10)
    bins = bin_splats(lo, hi, valid & in_range, leaves[2].detach(), 12, 10, 8)

    def channels_alpha_wz(t):  # the median depth is piecewise constant: not for finite differences
        return composite_view(t, bins, lo, hi, 12, 10, True)[..., :-1]

    assert torch.autograd.gradcheck(channels_alpha_wz, (table,), eps=1e-7, atol=1e-5, rtol=1e-4)


def test_same_result_with_one_and_two_threads():
    leaves, in_range = view_inputs(300, 12)
    runs = []
    try:
        for n in (1, 2):
            numba_jit.set_threads(n)
            img = rasterize_view(*leaves, in_range, W, H, composite="numba")
            runs.append((img, torch.autograd.grad(img.sum(), leaves)))
    finally:
        numba_jit.set_threads(None)
    assert torch.equal(runs[0][0], runs[1][0])  # tiles are independent, the gradient sum is ordered
    assert all(torch.equal(a, b) for a, b in zip(runs[0][1], runs[1][1]))


def test_backend_selection():
    cpu, cuda = torch.device("cpu"), torch.device("cuda")
    assert _resolve_backend("auto", cpu) == "numba"
    assert _resolve_backend("torch", cpu) == "torch"
    assert tile_backend("auto", cpu) == "numba" and tile_backend("torch", cpu) == "torch"
    with pytest.raises(ValueError, match="CPU"):
        _resolve_backend("numba", cuda)
    with pytest.raises(ValueError, match="gsplat"):
        tile_backend("gsplat", cpu)


def test_bad_input_is_refused():
    leaves, in_range = view_inputs(20, 13, width=16, height=16)
    table = surfel_table(*[x.detach() for x in leaves])
    lo, hi, valid = pixel_bounds(leaves[0].detach(), leaves[1].detach(), leaves[3].detach(), 16, 16)
    bins = bin_splats(lo, hi, valid & in_range, leaves[2].detach(), 16, 16, 8)
    with pytest.raises(ValueError, match="float32 or float64"):
        composite_view(table.half(), bins, lo, hi, 16, 16, True)
    with pytest.raises(ValueError, match="do not cover"):
        composite_view(table, bins, lo, hi, 32, 16, True)
    with pytest.raises(ValueError, match="support boxes"):
        composite_view(table, bins, lo[:, :1], hi, 16, 16, True)
    with pytest.raises(ValueError, match="surfel table"):
        composite_view(table[:, :5], bins, lo, hi, 16, 16, True)
    with pytest.raises(ValueError, match="composite"):
        rasterize_view(*leaves, in_range, 16, 16, composite="cuda")


def test_cache_falls_back_when_no_cache_dir_is_writable(monkeypatch):
    """With no writable locator numba refuses cache=True; njit_cached then uses a temp folder."""
    from numba.core import caching

    monkeypatch.setattr(caching.CacheImpl, "_locator_classes", [caching.UserProvidedCacheLocator])
    monkeypatch.setattr(numba.config, "CACHE_DIR", "")

    def hypot(x, y):
        return math.sqrt(x * x + y * y)

    with pytest.raises(RuntimeError, match="no locator"):
        numba.njit(cache=True)(hypot)  # what a read-only install without a writable home meets
    fn = numba_jit.njit_cached()(hypot)
    assert numba.config.CACHE_DIR == numba_jit.fallback_cache_dir()
    assert fn(3.0, 4.0) == 5.0


def test_auto_reaches_the_numba_compositor_in_the_pipelines(monkeypatch):
    """Stage 0 (recon.render), lattice renders (Stage I), Stage III and relighting: on CPU
    their default backend ("auto") composites through NumbaComposite."""
    from gspi.gaussians import numba_composite
    from tests.raster_fixtures import assert_cpu_pipelines_call

    assert_cpu_pipelines_call(monkeypatch, numba_composite.NumbaComposite, "the numba compositor")


def test_tile_order_deals_long_and_short_tiles_to_every_thread():
    """Each thread's contiguous share of the order (what numba's workqueue hands it) holds
    every tile once overall and a balanced mix of list lengths."""
    import numpy as np

    from gspi.gaussians.numba_composite import _tile_order

    counts = np.random.default_rng(0).geometric(0.05, size=256)  # 16 x 16 tiles, skewed lengths
    offsets = np.concatenate([[0], np.cumsum(counts)])
    plain = _tile_order(offsets)
    assert plain.tolist() == np.argsort(-counts, kind="stable").tolist()
    for workers in (2, 4):  # 256 tiles: equal shares
        order = _tile_order(offsets, workers)
        assert sorted(order.tolist()) == list(range(len(counts)))
        shares = [counts[part].sum() for part in np.array_split(order, workers)]
        assert max(shares) / min(shares) < 1.05, shares
    halves = [counts[part].sum() for part in np.array_split(plain, 2)]
    assert max(halves) / min(halves) > 2  # what the longest-first order gave the two threads

"""The compiled per-view projection (gspi/gaussians/numba_projection.py) against the torch ops.

``project_view`` must return what ``projection.project_surfels`` + ``sh.sh_colors`` +
``torch_backend.surfel_table`` compute, and the same gradients (with Stage 0's densification
shift ``delta``, gsplat's ``gradient_2dgs``). In float64 the two agree to ~1e-12 relative
(measured <= 2e-12 at 300 surfels, SH degree 3); the tolerance is 1e-9. In float32 the kernels
compute in float64 inside, so they are never further from the float64 result than the torch
float32 ops are. Then the two entry points that use it on CPU, ``rasterize_2dgs`` and
``recon.render.render_views``, against their torch paths.
"""

from __future__ import annotations

import pytest
import torch

from gspi.gaussians import numba_projection
from gspi.gaussians.numba_projection import project_view
from gspi.gaussians.projection import project_surfels
from gspi.gaussians.rasterize import rasterize_2dgs
from gspi.gaussians.sh import num_sh_bases, sh_colors
from gspi.gaussians.torch_backend import surfel_table
from gspi.recon.render import render_views
from tests.raster_fixtures import assert_cpu_pipelines_call, random_scene

W, H = 64, 48
F64 = torch.float64
OUTPUTS = ("geometry", "rgb", "normals")
LEAVES = ("means", "quats", "scales", "opacities", "sh", "delta")


def _rotation_x(angle: float, dtype=F64) -> torch.Tensor:
    c, s = torch.cos(torch.tensor(angle, dtype=dtype)), torch.sin(torch.tensor(angle, dtype=dtype))
    vm = torch.eye(4, dtype=dtype)
    vm[1, 1], vm[1, 2], vm[2, 1], vm[2, 2] = c, -s, s, c
    vm[:3, 3] = torch.tensor([0.1, -0.2, 0.3], dtype=dtype)
    return vm


def _intrinsics(width=W, height=H, dtype=F64, focal=60.0) -> torch.Tensor:
    return torch.tensor([[focal, 0.0, width / 2], [0.0, focal, height / 2], [0.0, 0.0, 1.0]], dtype=dtype)


def reference_view(means, quats, scales, opacities, sh, delta, viewmat, cam_k, degree):
    """The torch ops project_view replaces (geometry columns, SH colour, normals, radii, M)."""
    proj = project_surfels(means, quats, scales, viewmat[None], cam_k[None], W, H, 0.01, 1e10)
    rt = proj.ray_transforms[0]
    z = rt[..., 2, 2].detach()  # recon.render's densification shift of column 2 (gradient_2dgs)
    shift = torch.stack([delta[:, 0] * z, delta[:, 1] * z, torch.zeros_like(z)], dim=-1)
    rt_shifted = torch.cat([rt[..., :2], (rt[..., 2] + shift)[..., None]], dim=-1)
    center = torch.linalg.inv(viewmat)[:3, 3]
    rgb = sh_colors(degree, sh, means, center)
    no_channels = torch.zeros(len(means), 0, dtype=means.dtype)
    geometry = surfel_table(rt_shifted, proj.means2d[0], proj.depths[0], opacities, no_channels)[:-1]
    return {"geometry": geometry, "rgb": rgb, "normals": proj.normals[0], "radii": proj.radii[0],
            "ray_transforms": rt.detach()}


def compiled_view(means, quats, scales, opacities, sh, delta, viewmat, cam_k, degree):
    v = project_view(means, quats, scales, opacities, viewmat, cam_k, W, H, sh=sh, sh_degree=degree, delta=delta)
    return {"geometry": v.geometry, "rgb": v.rgb, "normals": v.normals, "radii": v.radii,
            "ray_transforms": v.ray_transforms}


def scene(n, seed, dtype=F64, bases=16):
    means, quats, scales, opacities, _ = random_scene(n, seed, dtype)
    sh = 0.3 * torch.randn(n, bases, 3, generator=torch.Generator().manual_seed(seed + 100), dtype=dtype)
    return [means, quats, scales, opacities, sh]


def run(fn, inputs, degree, viewmat, cam_k, seed=5):
    """Outputs and the gradients of a random linear loss of geometry, colour and normals."""
    leaves = [t.detach().clone().requires_grad_() for t in inputs]
    delta = torch.zeros(len(inputs[0]), 2, dtype=inputs[0].dtype, requires_grad=True)
    out = fn(*leaves, delta, viewmat.to(inputs[0].dtype), cam_k.to(inputs[0].dtype), degree)
    gen = torch.Generator().manual_seed(seed)
    loss = sum((out[k] * torch.randn(out[k].shape, generator=gen, dtype=F64).to(out[k].dtype)).sum()
               for k in OUTPUTS)
    grads = torch.autograd.grad(loss, leaves + [delta])
    return {k: v.detach() for k, v in out.items()}, dict(zip(LEAVES, grads))


def rel_err(actual, expected) -> float:
    actual, expected = actual.detach().double(), expected.detach().double()
    return float((actual - expected).abs().max()) / max(float(expected.abs().max()), 1e-30)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_matches_the_torch_ops_float64(degree):
    """Every output and every gradient, with more SH bases than the degree uses (the rest get 0)."""
    inputs, vm, K = scene(300, degree), _rotation_x(0.3), _intrinsics()
    out_t, grad_t = run(reference_view, inputs, degree, vm, K)
    out_n, grad_n = run(compiled_view, inputs, degree, vm, K)
    assert torch.equal(out_n["radii"], out_t["radii"])
    for key in OUTPUTS + ("ray_transforms",):
        assert out_n[key].shape == out_t[key].shape and out_n[key].dtype == F64
        assert rel_err(out_n[key], out_t[key]) < 1e-9, key
    for key in LEAVES:
        assert rel_err(grad_n[key], grad_t[key]) < 1e-9, f"d/d {key}"
    assert not grad_n["sh"][:, num_sh_bases(degree):].any()
    assert float(grad_n["delta"].abs().max()) > 0  # the densification statistic is not silently zero


def test_float32_is_no_further_from_float64_than_the_torch_ops():
    inputs, vm, K = scene(300, 7), _rotation_x(-0.2), _intrinsics()
    out64, grad64 = run(reference_view, inputs, 3, vm, K)
    inputs32 = [t.float() for t in inputs]
    out_t, grad_t = run(reference_view, inputs32, 3, vm, K)
    out_n, grad_n = run(compiled_view, inputs32, 3, vm, K)
    for key in OUTPUTS:
        assert out_n[key].dtype == torch.float32
        assert rel_err(out_n[key], out64[key]) <= max(rel_err(out_t[key], out64[key]), 1e-6), key
    for key in LEAVES:
        assert grad_n[key].dtype == torch.float32
        assert rel_err(grad_n[key], grad64[key]) <= max(rel_err(grad_t[key], grad64[key]), 1e-6), f"d/d {key}"


def test_degenerate_surfels_match_and_stay_finite():
    """A zero quaternion (normalised by max(|q|, eps), as torch does), zero scales, a surfel
    behind the camera and one beyond the far plane."""
    inputs = scene(40, 3)
    means, quats, scales = inputs[0], inputs[1], inputs[2]
    quats[5] = 0.0
    scales[6] = 0.0
    scales[7, 1] = 0.0
    means[8] = torch.tensor([0.0, 0.0, -2.0], dtype=F64)
    vm, K = torch.eye(4, dtype=F64), _intrinsics()
    out_t, grad_t = run(reference_view, inputs, 2, vm, K)
    out_n, grad_n = run(compiled_view, inputs, 2, vm, K)
    assert torch.equal(out_n["radii"], out_t["radii"]) and int(out_n["radii"][8].abs().sum()) == 0
    for key in OUTPUTS:
        finite = torch.isfinite(out_t[key])
        assert torch.equal(torch.isfinite(out_n[key]), finite), key
        assert rel_err(out_n[key][finite], out_t[key][finite]) < 1e-9, key
    for key in LEAVES:
        finite = torch.isfinite(grad_t[key])
        assert rel_err(grad_n[key][finite], grad_t[key][finite]) < 1e-9, f"d/d {key}"


def test_without_sh_there_is_no_colour_and_no_sh_gradient():
    means, quats, scales, opacities, _ = scene(50, 4)
    leaves = [t.clone().requires_grad_() for t in (means, quats, scales, opacities)]
    v = project_view(*leaves, _rotation_x(0.1), _intrinsics(), W, H)
    assert v.rgb is None and v.geometry.shape == (50, 14)
    (v.geometry.sum() + v.normals.sum()).backward()
    assert all(t.grad is not None and torch.isfinite(t.grad).all() for t in leaves)
    assert torch.equal(v.means2d, v.geometry[:, 10:12]) and torch.equal(v.depths, v.geometry[:, 13])


def test_bad_input_is_refused():
    means, quats, scales, opacities, sh = scene(10, 5)
    vm, K = torch.eye(4, dtype=F64), _intrinsics()
    with pytest.raises(ValueError, match="float32 / float64"):
        project_view(means.half(), quats, scales, opacities, vm, K, W, H)
    with pytest.raises(ValueError, match="together"):
        project_view(means, quats, scales, opacities, vm, K, W, H, sh=sh)
    with pytest.raises(ValueError, match=r"SH degree 3 needs sh \[N, >= 16, 3\]"):
        project_view(means, quats, scales, opacities, vm, K, W, H, sh=sh[:, :9], sh_degree=3)


def _cameras(n_cams, width, height, dtype=F64):
    angles = torch.linspace(-0.2, 0.2, n_cams, dtype=dtype)
    vms = torch.eye(4, dtype=dtype).repeat(n_cams, 1, 1)
    vms[:, 0, 0], vms[:, 0, 2], vms[:, 2, 0], vms[:, 2, 2] = angles.cos(), angles.sin(), -angles.sin(), angles.cos()
    return vms, _intrinsics(width, height, dtype, focal=40.0).repeat(n_cams, 1, 1)


def _both_backends(render, leaves):
    """{backend: (outputs, leaf gradients)} of a weighted sum of every output of render(backend)."""
    result = {}
    for backend in ("torch", "numba"):
        outs = render(backend)
        loss = sum((i + 1) * t.sum() for i, t in enumerate(outs))
        grads = torch.autograd.grad(loss, leaves, allow_unused=True)
        result[backend] = ([t.detach() for t in outs], grads)
    return result


@pytest.mark.parametrize("colour_kind", ["plain", "per_view_plain", "per_view_sh"])
def test_rasterize_2dgs_colour_kinds_match_torch(colour_kind):
    """Plain colours [N, D] and [C, N, D] and per-view SH [C, N, K, 3] through the fused path."""
    means, quats, scales, opacities, _ = random_scene(80, 20)
    gen = torch.Generator().manual_seed(20)
    n_cams = 2
    colours, degree = {
        "plain": (torch.rand(80, 4, generator=gen, dtype=F64), None),
        "per_view_plain": (torch.rand(n_cams, 80, 2, generator=gen, dtype=F64), None),
        "per_view_sh": (0.3 * torch.randn(n_cams, 80, 9, 3, generator=gen, dtype=F64), 2),
    }[colour_kind]
    leaves = [t.clone().requires_grad_() for t in (means, quats, scales, opacities, colours)]
    vms, Ks = _cameras(n_cams, 32, 24)

    def render(backend):
        out = rasterize_2dgs(*leaves, vms, Ks, 32, 24, sh_degree=degree, backend=backend, depth_point="center")
        return out.rgb, out.alpha, out.depth_expected, out.normals

    result = _both_backends(render, leaves)
    for a, b in zip(result["numba"][0], result["torch"][0]):
        assert a.shape == b.shape and rel_err(a, b) < 1e-6
    for g_n, g_t, name in zip(result["numba"][1], result["torch"][1], ("means", "quats", "scales", "opacities", "colours")):
        assert rel_err(g_n, g_t) < 1e-6, f"d/d {name}"


def test_render_views_densification_gradient_matches_torch():
    """Stage 0's renderer: images, leaf gradients and gradient_2dgs (the delta's gradient) equal."""
    means, quats, scales, opacities, _ = random_scene(150, 21)
    sh = 0.3 * torch.randn(150, 16, 3, generator=torch.Generator().manual_seed(21), dtype=F64)
    leaves = [t.clone().requires_grad_() for t in (means, quats, scales, opacities, sh)]
    vms, Ks = _cameras(3, 40, 32)
    result = {}
    for backend in ("torch", "numba"):
        out = render_views(*leaves, 3, vms, Ks, 40, 32, backgrounds=torch.ones(3, 3, dtype=F64),
                           densify_grad=True, backend=backend)
        images = (out.rgb, out.alpha, out.depth_expected, out.depth_median, out.normals)
        delta = out.meta["gradient_2dgs"]
        assert delta.shape == (3, 150, 2)
        loss = sum((i + 1) * t.sum() for i, t in enumerate(images))
        result[backend] = ([t.detach() for t in images], torch.autograd.grad(loss, leaves + [delta]))
    for a, b in zip(result["numba"][0], result["torch"][0]):
        assert rel_err(a, b) < 1e-6
    for g_n, g_t, name in zip(result["numba"][1], result["torch"][1], LEAVES):
        assert rel_err(g_n, g_t) < 1e-6, f"d/d {name}"
    assert float(result["torch"][1][-1].abs().max()) > 0


def test_camera_gradients_take_the_torch_path():
    """The compiled projection has no camera gradient: a viewmat that requires grad still gets one."""
    means, quats, scales, opacities, colours = random_scene(40, 22)
    vms, Ks = _cameras(1, 16, 16)
    grads = {}
    for backend in ("torch", "numba"):
        vm = vms.clone().requires_grad_()
        out = rasterize_2dgs(means, quats, scales, opacities, colours, vm, Ks, 16, 16, backend=backend)
        grads[backend] = torch.autograd.grad(out.rgb.sum(), vm)[0]
    assert float(grads["torch"].abs().max()) > 0
    assert torch.allclose(grads["numba"], grads["torch"], rtol=1e-6, atol=1e-9)


def test_auto_reaches_the_compiled_projection_in_the_pipelines(monkeypatch):
    """Stage 0, lattice renders (Stage I), Stage III and relighting project through it on CPU."""
    assert_cpu_pipelines_call(monkeypatch, numba_projection.NumbaViewProjection, "the compiled projection")

"""gspi-data device=auto|cpu|cuda: what the generator makes lands on the device asked for.

No GPU here, so torch's meta device stands in for CUDA: a CPU tensor mixed into a meta
computation raises, so these pass only if every constant of the SDFs, patterns and materials
and every prefiltered environment is made on the device of its inputs. The byte-identity of
device=auto/cpu is tested with the other determinism tests (tests/test_data_generate.py); the
real CUDA run is benchmarks/gpu_check.py's `data_eval_cuda` step.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from gspi.data.procedural.materials import MATERIAL_CLASSES, evaluate_material, sample_material
from gspi.data.procedural.sdf_shapes import FAMILIES, ShapeSDF, sample_shape

META = torch.device("meta")


class _Reached(Exception):
    """Raised by a stand-in once it has recorded what it was given."""


@pytest.mark.parametrize("seed", range(4))
def test_every_material_class_evaluates_on_the_points_device(seed):
    q = torch.rand(16, 3, device=META)
    for cls in MATERIAL_CLASSES:
        m = evaluate_material(sample_material(cls, np.random.default_rng(seed)), q)
        assert {m.albedo_linear.device, m.roughness.device, m.metallic.device} == {META}, cls


@pytest.mark.parametrize("seed", range(3))
def test_every_shape_family_evaluates_on_the_points_device(seed):
    p = torch.rand(16, 3, device=META)
    for family in FAMILIES:
        shape = ShapeSDF(sample_shape(family, np.random.default_rng(seed)))
        assert shape(p).device == META and shape.local(p).device == META, family


def test_the_renderer_traces_on_the_device_asked_for(monkeypatch):
    """render_views moves the (CPU-drawn) rays to `device` before tracing."""
    import gspi.data.procedural.render_view as render_view
    from gspi.data.lattice import lattice_cameras

    seen = {}

    def fake_trace(sdf, origins, directions, **kwargs):
        seen["devices"] = {origins.device, directions.device}
        raise _Reached

    monkeypatch.setattr(render_view, "sphere_trace", fake_trace)
    K, w2c = lattice_cameras(width=8, height=8, num_views=2, radius=3.0, fov_deg=45.0)
    shape = ShapeSDF(sample_shape("sphere", np.random.default_rng(0)))
    with pytest.raises(_Reached):
        render_view.render_views(shape, {}, [(K[0], w2c[0], 1)], 8, 8, env=None, supersample=1,
                                 device=META)
    assert seen["devices"] == {META}


def test_generate_dataset_hands_its_device_to_every_scene(tmp_path, monkeypatch):
    """generate_dataset(device=) reaches the scene renderer, with the environments prefiltered
    there and the maps written to envmaps/ left on the CPU."""
    import gspi.data.generate as generate

    seen = {}

    def fake_generate_scene(recipe, out_dir, *, envs, prefiltered, device, **kwargs):
        seen.update(device=device, envs={e.device for e in envs.values()},
                    pre={p.irradiance.device for p in prefiltered.values()})
        raise _Reached

    monkeypatch.setattr(generate, "generate_scene", fake_generate_scene)
    cfg = generate.BenchmarkConfig(num_train_scenes=1, num_val_scenes=0, num_test_scenes=0,
                                   image_size=8, env_height=8, num_relight_envs=1)
    with pytest.raises(_Reached):
        generate.generate_dataset(Path(tmp_path) / "d", cfg, seed=0, device=META)
    assert seen == {"device": META, "envs": {torch.device("cpu")}, "pre": {META}}

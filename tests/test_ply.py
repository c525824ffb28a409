"""Tests for gspi.gaussians.ply: official 2DGS layout, round trip, malformed files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from plyfile import PlyData, PlyElement

from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.ply import PlyFormatError, property_names, read_ply, write_ply
from tests.fixtures import random_gaussians

FIXTURE = Path(__file__).parent / "data" / "ply" / "official_2dgs_sh3.ply"


def official_attribute_names(n_rest: int = 45) -> list[str]:
    """hbb1 GaussianModel.construct_list_of_attributes, transcribed."""
    names = ["x", "y", "z", "nx", "ny", "nz"]
    names += [f"f_dc_{i}" for i in range(3)]
    names += [f"f_rest_{i}" for i in range(n_rest)]
    names.append("opacity")
    names += [f"scale_{i}" for i in range(2)]
    names += [f"rot_{i}" for i in range(4)]
    return names


def official_fixture_arrays(n: int = 5) -> dict[str, np.ndarray]:
    """Deterministic raw parameters of the fixture, shaped as hbb1 stores them."""
    i = np.arange(n, dtype=np.float32)[:, None]
    return {
        "xyz": np.concatenate([0.1 * i, -0.2 * i, 1.0 + 0.05 * i], axis=1).astype(np.float32),
        "features_dc": (0.3 - 0.1 * i)[:, None, :].repeat(3, axis=2) + np.float32([0.0, 0.01, 0.02]),  # [N, 1, 3]
        # [N, 15, 3]: value = row + coefficient / 100 + channel / 1000, so the layout is visible
        "features_rest": (
            i[:, :, None] + np.arange(15, dtype=np.float32)[None, :, None] / 100 + np.arange(3, dtype=np.float32) / 1000
        ).astype(np.float32),
        "opacity": (np.linspace(-2.0, 2.0, n, dtype=np.float32))[:, None],
        "scale": np.log(np.float32([[0.01, 0.02]]) * (1 + i)).astype(np.float32),
        "rotation": np.concatenate([1 + i, 0.5 * i, -0.25 * i, 0.1 + 0 * i], axis=1).astype(np.float32),
    }


def write_official_fixture(path: Path, n: int = 5) -> None:
    """Writes a PLY exactly like hbb1 GaussianModel.save_ply (plyfile, float32)."""
    a = official_fixture_arrays(n)
    f_dc = a["features_dc"].transpose(0, 2, 1).reshape(n, -1)
    f_rest = a["features_rest"].transpose(0, 2, 1).reshape(n, -1)
    normals = np.zeros_like(a["xyz"])
    attributes = np.concatenate([a["xyz"], normals, f_dc, f_rest, a["opacity"], a["scale"], a["rotation"]], axis=1)
    elements = np.empty(n, dtype=[(name, "f4") for name in official_attribute_names()])
    elements[:] = list(map(tuple, attributes))
    PlyData([PlyElement.describe(elements, "vertex")]).write(str(path))


def assert_bit_equal(a: Gaussians2D, b: Gaussians2D) -> None:
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh_dc", "sh_rest",
                 "albedo_logits", "roughness_logits", "metallic_logits"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.dtype == y.dtype == torch.float32, name
            assert torch.equal(x.view(torch.int32), y.view(torch.int32)), name


class TestOfficialFixture:
    def test_fixture_matches_generator(self, tmp_path):
        # the committed file is exactly what the hbb1 save_ply transcription writes
        write_official_fixture(tmp_path / "regen.ply")
        assert (tmp_path / "regen.ply").read_bytes() == FIXTURE.read_bytes()

    def test_header_is_official_order(self):
        ply = PlyData.read(str(FIXTURE))
        assert [p.name for p in ply["vertex"].properties] == official_attribute_names()
        assert len(official_attribute_names()) == 61
        assert ply.header.startswith("ply\nformat binary_little_endian 1.0")

    def test_load_raw_values_and_layout(self):
        g = read_ply(FIXTURE)
        a = official_fixture_arrays()
        assert g.num_gaussians == 5 and g.sh_degree == 3 and not g.has_pbr
        np.testing.assert_array_equal(g.means.numpy(), a["xyz"])
        np.testing.assert_array_equal(g.sh_dc.numpy(), a["features_dc"])
        np.testing.assert_array_equal(g.sh_rest.numpy(), a["features_rest"])  # channel-major undone
        np.testing.assert_array_equal(g.opacity_logits.numpy(), a["opacity"][:, 0])
        np.testing.assert_array_equal(g.log_scales.numpy(), a["scale"])
        np.testing.assert_array_equal(g.quats.numpy(), a["rotation"])

    def test_activations(self):
        g = read_ply(FIXTURE)
        a = official_fixture_arrays()
        np.testing.assert_allclose(g.opacities.numpy(), 1 / (1 + np.exp(-a["opacity"][:, 0])), rtol=1e-6)
        scales = np.float32([[0.01, 0.02]]) * (1 + np.arange(5))[:, None]
        np.testing.assert_allclose(g.scales.numpy(), scales, rtol=1e-6)
        q = a["rotation"] / np.linalg.norm(a["rotation"], axis=1, keepdims=True)
        np.testing.assert_allclose(g.rotations.numpy(), q, rtol=1e-6)
        base = 0.5 + 0.28209479177387814 * a["features_dc"][:, 0]
        np.testing.assert_allclose(g.base_color().numpy(), base, rtol=1e-6)
        assert g.sh.shape == (5, 16, 3)

    def test_rewrite_is_byte_identical(self, tmp_path):
        write_ply(tmp_path / "out.ply", read_ply(FIXTURE))
        assert (tmp_path / "out.ply").read_bytes() == FIXTURE.read_bytes()


class TestRoundTrip:
    @pytest.mark.parametrize("degree", [0, 1, 2, 3])
    @pytest.mark.parametrize("pbr", [False, True])
    def test_bit_exact(self, tmp_path, degree, pbr):
        g = random_gaussians(7, degree, pbr)
        write_ply(tmp_path / "g.ply", g)
        back = read_ply(tmp_path / "g.ply")
        assert back.sh_degree == degree and back.has_pbr == pbr
        assert_bit_equal(g, back)

    def test_property_order(self, tmp_path):
        write_ply(tmp_path / "g.ply", random_gaussians(3, 3, True))
        names = [p.name for p in PlyData.read(str(tmp_path / "g.ply"))["vertex"].properties]
        assert names == official_attribute_names() + ["albedo_0", "albedo_1", "albedo_2", "roughness", "metallic"]
        assert names == property_names(3, pbr=True)

    def test_zero_gaussians(self, tmp_path):
        write_ply(tmp_path / "g.ply", random_gaussians(0, 1, False))
        assert read_ply(tmp_path / "g.ply").num_gaussians == 0

    def test_any_property_order_and_float64(self, tmp_path):
        g = random_gaussians(4, 1, False)
        data = PlyData.read(str(_write(tmp_path / "a.ply", g)))["vertex"].data
        names = list(reversed(data.dtype.names))
        shuffled = np.empty(len(data), dtype=[(n, "<f8") for n in names])
        for n in names:
            shuffled[n] = data[n]
        PlyData([PlyElement.describe(shuffled, "vertex")]).write(str(tmp_path / "b.ply"))
        assert_bit_equal(g, read_ply(tmp_path / "b.ply"))


def _write(path: Path, g: Gaussians2D) -> Path:
    write_ply(path, g)
    return path


def _records(names: list[str], n: int = 3, fill: float = 0.5) -> np.ndarray:
    rec = np.empty(n, dtype=[(name, "<f4") for name in names])
    for name in names:
        rec[name] = fill
    return rec


def _write_records(path: Path, rec: np.ndarray, element: str = "vertex") -> Path:
    PlyData([PlyElement.describe(rec, element)]).write(str(path))
    return path


class TestMalformed:
    def _check(self, path: Path, fragment: str) -> None:
        with pytest.raises(PlyFormatError) as info:
            read_ply(path)
        assert str(path) in str(info.value)
        assert fragment in str(info.value)
        assert isinstance(info.value, ValueError)

    def test_not_a_ply(self, tmp_path):
        (tmp_path / "x.ply").write_text("hello world\n")
        self._check(tmp_path / "x.ply", "not a readable PLY")

    def test_empty_file(self, tmp_path):
        (tmp_path / "x.ply").write_bytes(b"")
        self._check(tmp_path / "x.ply", "not a readable PLY")

    def test_no_vertex_element(self, tmp_path):
        path = _write_records(tmp_path / "x.ply", _records(official_attribute_names()), element="face")
        self._check(path, "no 'vertex' element")

    def test_missing_required_property(self, tmp_path):
        names = [n for n in official_attribute_names() if n != "rot_3"]
        self._check(_write_records(tmp_path / "x.ply", _records(names)), "rot_3")

    def test_wrong_f_rest_count(self, tmp_path):
        self._check(_write_records(tmp_path / "x.ply", _records(official_attribute_names(n_rest=44))), "44 f_rest")

    def test_f_rest_gap(self, tmp_path):
        names = [n for n in official_attribute_names(n_rest=46) if n != "f_rest_3"]
        self._check(_write_records(tmp_path / "x.ply", _records(names)), "without gaps")

    def test_truncated_binary(self, tmp_path):
        full = _write(tmp_path / "full.ply", random_gaussians(6, 3, False)).read_bytes()
        (tmp_path / "x.ply").write_bytes(full[:-10])
        self._check(tmp_path / "x.ply", "early end-of-file")

    @pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
    def test_non_finite(self, tmp_path, bad):
        rec = _records(official_attribute_names())
        rec["scale_1"][1] = bad
        self._check(_write_records(tmp_path / "x.ply", rec), "'scale_1' of vertex 1")

    def test_incomplete_pbr(self, tmp_path):
        rec = _records(official_attribute_names() + ["albedo_0", "albedo_1", "albedo_2"])
        self._check(_write_records(tmp_path / "x.ply", rec), "incomplete PBR")

    def test_3dgs_file_missing_a_property(self, tmp_path):
        names = [n for n in official_attribute_names() if n != "rot_3"] + ["scale_2"]
        self._check(_write_records(tmp_path / "x.ply", _records(names)), "3D Gaussian splatting file")

    def test_missing_file_is_not_format_error(self, tmp_path):
        with pytest.raises(FileNotFoundError):
            read_ply(tmp_path / "absent.ply")

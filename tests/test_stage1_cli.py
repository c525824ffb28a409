"""Stage I config + CLI (gspi-extract), the subsample knob, and Table 2's measure on a generated
point cloud (gspi/stage2/score_generated.py)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from eval.common.conf import CONF_DIR
from gspi.cli.extract import run
from gspi.gaussians.ply import write_ply
from gspi.stage1.config import Stage1Config
from gspi.stage1.extract import maybe_subsample
from gspi.point_cloud import PointCloud
from gspi.stage2.points_measure import PSNR_CAP_DB
from gspi.point_cloud import nearest_fill, scatter_pixel_values
from gspi.stage2.score_generated import gt_oracle_pbr, scatter_point_values, score_generated_points
from tests.fixtures import surfel_sphere
from tests.stage2_fixtures import make_lattice_scene

SIZE = 32  # the lattice scene's size (the smallest LPIPS accepts)


def random_cloud(n: int, *, views: int = 4, size: int = 8, seed: int = 0) -> PointCloud:
    rng = np.random.default_rng(seed)
    return PointCloud(xyz=rng.normal(size=(n, 3)).astype(np.float32),
                      view=rng.integers(0, views, n).astype(np.int32),
                      pixel=rng.integers(0, size, (n, 2)).astype(np.int32),
                      rgb=rng.uniform(size=(n, 3)).astype(np.float32), image_size=(size, size))


class TestConfig:
    def test_from_dict_nested_values(self):
        cfg = Stage1Config.from_dict({"image_size": 64, "depth_consensus": {"tolerance_px": 2.5},
                                      "max_points": 100})
        assert cfg.image_size == 64 and cfg.depth_consensus.tolerance_px == 2.5
        assert cfg.depth_consensus.num_neighbours == 6 and cfg.outliers.enabled and cfg.max_points == 100

    @pytest.mark.parametrize("data,key", [({"image_sise": 64}, "stage1.image_sise"),
                                          ({"outliers": {"std": 2.0}}, "stage1.outliers.std")])
    def test_unknown_key_is_named(self, data, key):
        with pytest.raises(ValueError, match=f"unknown stage1 config key.*{key}"):
            Stage1Config.from_dict(data)

    @pytest.mark.parametrize("option,size", [("default", 128), ("paper", 512), ("tiny", 48)])
    def test_every_option_composes(self, option, size):
        with initialize_config_dir(version_base="1.3", config_dir=CONF_DIR):
            cfg = compose("gspi_extract", overrides=["asset=a.ply", "out=o", f"stage1={option}"])
        from omegaconf import OmegaConf
        s1 = Stage1Config.from_dict(OmegaConf.to_container(cfg.stage1))
        assert s1.name == option and s1.image_size == size and s1.max_points is None
        assert s1.lattice == {"num_views": 32, "radius": 3.0, "fov_deg": 45.0, "min_elevation_deg": 0.0}


class TestSubsample:
    def test_seeded_deterministic_and_ordered(self):
        cloud = random_cloud(500)
        a, b = maybe_subsample(cloud, 100, 7), maybe_subsample(cloud, 100, 7)
        assert len(a) == 100
        np.testing.assert_array_equal(a.xyz, b.xyz)
        assert not np.array_equal(a.xyz, maybe_subsample(cloud, 100, 8).xyz)
        # a subset of the original points, in their original order, rows kept together
        idx = [int(np.flatnonzero((cloud.xyz == p).all(1))[0]) for p in a.xyz]
        assert idx == sorted(idx) and len(set(idx)) == 100
        np.testing.assert_array_equal(a.rgb, cloud.rgb[idx])
        assert a.image_size == cloud.image_size

    def test_none_or_large_keeps_all(self):
        cloud = random_cloud(50)
        assert maybe_subsample(cloud, None, 0) is cloud and maybe_subsample(cloud, 50, 0) is cloud
        with pytest.raises(ValueError, match="max_points"):
            maybe_subsample(cloud, 0, 0)


class TestScatter:
    def test_round_trip_and_hit_count(self):
        cloud = random_cloud(300, size=8)
        # keep one point per (view, pixel) for the exact round trip
        _, first = np.unique(np.c_[cloud.view, cloud.pixel], axis=0, return_index=True)
        unique = cloud.subset(np.sort(first))
        values = np.random.default_rng(1).uniform(size=(len(unique), 5)).astype(np.float32)
        maps, hit = scatter_point_values(unique, values, height=8, width=8, num_views=4)
        assert maps.shape == (4, 8, 8, 5) and hit.shape == (4, 8, 8)
        np.testing.assert_array_equal(maps[unique.view, unique.pixel[:, 0], unique.pixel[:, 1]], values)
        assert hit.sum() == len(unique) and not maps[~hit].any()
        # with duplicates: the hit count is the number of distinct (view, pixel)
        _, hit_all = scatter_point_values(cloud, np.ones((len(cloud), 1)), height=8, width=8, num_views=4)
        assert hit_all.sum() == len(first) < len(cloud)

    def test_duplicates_average(self):
        maps, hit = scatter_pixel_values(np.array([1, 1, 0]), np.array([[2, 3], [2, 3], [0, 0]]),
                                         np.array([[1.0], [3.0], [5.0]]), height=4, width=5, num_views=2)
        assert maps[1, 2, 3, 0] == 2.0 and maps[0, 0, 0, 0] == 5.0 and hit.sum() == 2

    def test_out_of_range_is_an_error(self):
        with pytest.raises(ValueError, match="outside 2 views of 4x5 px"):
            scatter_pixel_values(np.array([0]), np.array([[4, 0]]), np.zeros((1, 1)), height=4, width=5,
                                 num_views=2)


def test_nearest_fill_hand_made():
    sub = np.array([[0.0, 0, 0], [1.0, 0, 0], [0.0, 5, 0]])
    values = np.array([[10.0, 1], [20.0, 2], [30.0, 3]])
    points_all = np.array([[0.1, 0, 0], [0.9, 0.2, 0], [0.0, 4, 1], [1.0, 0, 0], [-3.0, 0, 0]])
    expect = values[[0, 1, 2, 1, 0]]
    np.testing.assert_array_equal(nearest_fill(sub, values, points_all), expect)
    cloud_all = PointCloud(xyz=points_all.astype(np.float32), view=np.zeros(5, np.int32),
                           pixel=np.zeros((5, 2), np.int32), rgb=np.zeros((5, 3), np.float32))
    np.testing.assert_array_equal(nearest_fill(sub, values, cloud_all), expect)


@pytest.fixture(scope="module")
def lattice_scene(tmp_path_factory) -> Path:
    return make_lattice_scene(tmp_path_factory.mktemp("s1scene"), "sphere", size=SIZE)


def gt_points_and_pbr(scene_dir: Path) -> tuple[PointCloud, np.ndarray]:
    """The scene's GT cloud as a Stage I cloud and its GT PBR values [P, 5]."""
    with np.load(scene_dir / "gt_points.npz") as gt:
        points = PointCloud(xyz=gt["xyz"], view=gt["view"], pixel=gt["pixel"], rgb=gt["rgb"],
                            image_size=(SIZE, SIZE))
        pbr = np.c_[gt["albedo"], gt["roughness"], gt["metallic"]]
    return points, pbr


class TestScoreGenerated:
    def test_gt_values_score_perfect(self, lattice_scene, lpips_net):
        points, pbr = gt_points_and_pbr(lattice_scene)
        scores = score_generated_points(points, pbr, lattice_scene, lpips_net=lpips_net)
        for group in ("albedo", "roughness", "metallic", "avg"):
            assert scores[group]["psnr"] == PSNR_CAP_DB
            assert scores[group]["ssim"] == pytest.approx(1.0, abs=1e-9)
            assert scores[group]["lpips"] == pytest.approx(0.0, abs=1e-6)

    def test_constant_offset_gives_known_psnr(self, lattice_scene, lpips_net):
        points, pbr = gt_points_and_pbr(lattice_scene)
        offset = 0.05
        # move every value by exactly `offset`, away from the nearer bound so it stays in [0, 1]
        pred = np.where(pbr < 0.5, pbr + offset, pbr - offset)
        golden = -10 * np.log10(offset ** 2)  # MSE = offset^2 on every scored pixel: 26.02 dB
        sub = points.subset(np.arange(0, len(points), 3))  # a subsample: only its pixels are scored
        scores = score_generated_points(sub, pred[::3], lattice_scene, lpips_net=lpips_net)
        for group in ("albedo", "roughness", "metallic", "avg"):
            assert scores[group]["psnr"] == pytest.approx(golden, abs=1e-3)
            assert scores[group]["ssim"] < 1.0

    def test_points_on_gt_background_are_not_scored(self, lattice_scene, lpips_net):
        points, pbr = gt_points_and_pbr(lattice_scene)
        # one extra point per view on a background corner pixel, with a wrong value
        extra = PointCloud(xyz=np.zeros((32, 3), np.float32), view=np.arange(32, dtype=np.int32),
                           pixel=np.zeros((32, 2), np.int32), rgb=np.zeros((32, 3), np.float32),
                           image_size=(SIZE, SIZE))
        both = PointCloud(**{k: np.r_[getattr(points, k), getattr(extra, k)] for k in ("xyz", "view", "pixel", "rgb")},
                          image_size=(SIZE, SIZE))
        scores = score_generated_points(both, np.r_[pbr, np.full((32, 5), 0.5)], lattice_scene, lpips_net=lpips_net)
        assert scores["avg"]["psnr"] == PSNR_CAP_DB

    def test_gt_oracle_on_the_gt_cloud_is_the_gt(self, lattice_scene):
        points, pbr = gt_points_and_pbr(lattice_scene)
        np.testing.assert_array_equal(gt_oracle_pbr(points, lattice_scene), pbr)

    def test_size_mismatch_is_a_clear_error(self, lattice_scene, lpips_net):
        points, pbr = gt_points_and_pbr(lattice_scene)
        points.image_size = (64, 64)
        with pytest.raises(ValueError, match="extracted at 64x64 px; rerun gspi-extract with stage1.image_size=32"):
            score_generated_points(points, pbr, lattice_scene, lpips_net=lpips_net)
        points.image_size = (SIZE, SIZE)
        with pytest.raises(ValueError, match=r"pbr must be \[P, 5\]"):
            score_generated_points(points, pbr[:, :3], lattice_scene, lpips_net=lpips_net)


def test_evaluate_points_scatter_is_the_same_code(lattice_scene):
    from gspi.stage2.data import load_scene_points
    from gspi.stage2.points_measure import scatter_to_views

    scene = load_scene_points(lattice_scene, None)
    points, pbr = gt_points_and_pbr(lattice_scene)
    maps, hit = scatter_to_views(pbr, scene)
    expect_maps, expect_hit = scatter_point_values(points, pbr, height=SIZE, width=SIZE)
    np.testing.assert_array_equal(maps, expect_maps)
    np.testing.assert_array_equal(hit, expect_hit)
    assert hit.sum() == scene.num_points  # GT clouds: one point per foreground pixel


class TestCli:
    def compose(self, tmp_path: Path, *overrides: str):
        asset = tmp_path / "asset.ply"
        write_ply(asset, surfel_sphere(1500, floaters=30))
        with initialize_config_dir(version_base="1.3", config_dir=CONF_DIR):
            return compose("gspi_extract", overrides=[f"asset={asset}", f"out={tmp_path / 'out'}",
                                                      "stage1=tiny", *overrides])

    def test_writes_points_and_report(self, tmp_path, lattice_scene):
        summary = run(self.compose(tmp_path, f"scene={lattice_scene}", f"stage1.image_size={SIZE}"))
        out = tmp_path / "out"
        points = PointCloud.load(out / "points.npz")
        saved = json.loads((out / "stage1.json").read_text())
        assert saved["num_points"] == len(points) == summary["num_points"] > 1000
        assert points.image_size == (SIZE, SIZE) and saved["image_size"] == [SIZE, SIZE]
        steps = [s["step"] for s in saved["filters"]]
        assert steps == ["unprojected", "statistical_outliers", "mask_consistency", "depth_consensus"]
        counts = [s["count"] for s in saved["filters"]]
        assert counts[-1] == len(points)
        for prev, step in zip(counts, saved["filters"][1:]):
            assert step["count"] == prev - step["removed"]
        assert sum(s["removed"] for s in saved["filters"][1:]) > 0  # the floaters go
        # the sphere asset and the scene's GT sphere share their surface (radius 0.8)
        kept = saved["filters"][-1]
        assert kept["median_px"] < 1.0 and kept["removed_median_px"] > 3.0 and kept["mean_dist"] < saved["filters"][0]["mean_dist"]
        assert saved["reference"]["spacing_floor"]["median_dist"] > 0
        assert saved["config"]["name"] == "tiny" and saved["scene"]["image_size"] == [SIZE, SIZE]

    def test_switches_and_subsample(self, tmp_path):
        summary = run(self.compose(tmp_path, "stage1.image_size=32", "stage1.outliers.enabled=false",
                                   "stage1.mask_consistency.enabled=false", "stage1.max_points=500"))
        assert [s["step"] for s in summary["filters"]] == ["unprojected", "depth_consensus"]
        assert "mean_dist" not in summary["filters"][0]  # no scene= -> no distances
        assert summary["num_points"] == 500 < summary["num_filtered"]
        assert len(PointCloud.load(tmp_path / "out" / "points.npz")) == 500

    def test_unknown_key_and_missing_asset(self, tmp_path):
        with pytest.raises(ValueError, match="stage1.outliers.ratio"):
            run(self.compose(tmp_path, "+stage1.outliers.ratio=3"))
        cfg = self.compose(tmp_path)
        cfg.asset = str(tmp_path / "nope.ply")
        with pytest.raises(FileNotFoundError, match="nope.ply: asset file not found"):
            run(cfg)


@pytest.mark.parametrize("build,where,bad", [("gspi.recon.trainer:ReconConfig", "recon.lr", {"lr": {"mean": 1}}),
                                             ("gspi.stage3.config:Stage3Config", "stage3.init",
                                              {"init": {"sh_gian": "chroma"}}),
                                             ("gspi.stage1.config:Stage1Config", "stage1", {"sise": 1})])
def test_every_stage_config_names_a_misspelt_key_and_its_place(build, where, bad):
    """The three stage configs share gspi.strict_config: the error gives the dotted path."""
    import importlib

    module, name = build.split(":")
    kind = getattr(importlib.import_module(module), name)
    key = next(iter(bad.values()))
    key = next(iter(key)) if isinstance(key, dict) else next(iter(bad))
    with pytest.raises(ValueError, match=rf"unknown {where.split('.')[0]} config key\(s\) "
                                         rf"\['{where}\.{key}'\]; allowed in {where}: \["):
        kind.from_dict(bad)
    with pytest.raises(ValueError, match=f"{where}: expected a mapping"):
        kind.from_dict({where.split(".")[1]: 3} if "." in where else 3)

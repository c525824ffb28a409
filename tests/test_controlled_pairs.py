"""gspi.data.controlled_pairs: each pair differs in its one property only, deterministic, disjoint."""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from eval.common.layout import read_scene, read_splits, read_view_file
from gspi.cli.data import run
from gspi.data.controlled_pairs import (KIND_MEMBERS, ControlledPairsConfig, controlled_pairs, read_manifest)
from gspi.data.generate import BenchmarkConfig, scene_recipes
from gspi.data.procedural.materials import METAL_F0
from gspi.strict_config import ConfigError
from tests.data_config import compose_data_config

# one family, one colour: a roughness pair and a metal pair, 4 scenes of 16 px
SHRUNK = ["data.image_size=16", "data.env_height=16", "data.supersample=1", "data.workers=1",
          "data.num_test_views=2", "data.num_val_views=1", "data.num_relight_envs=1",
          "data.controlled_pairs.families=[torus]", "data.controlled_pairs.colours=1",
          "data.point_clouds=false", "data.contact_sheets=false"]
VIEWS = dict(num_test_views=8, num_val_views=4, num_relight_envs=4,
             lattice={"num_views": 32, "radius": 3.0, "fov_deg": 45.0})


def make_config(out: Path, seed: int = 0, extra: list[str] | None = None):
    return compose_data_config("controlled_pairs", out, seed, [*SHRUNK, *(extra or [])])


def hashes(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and ".hydra" not in p.parts and p.suffix != ".log"}


@pytest.fixture(scope="module")
def pairs_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("pairs") / "pairs"
    run(make_config(out))
    return out


@pytest.fixture(scope="module")
def default_pairs() -> tuple[list[dict], list[dict]]:
    return controlled_pairs(0, ControlledPairsConfig(), **VIEWS)


def test_default_preset_makes_every_kind_family_colour_once(default_pairs):
    entries, recipes = default_pairs
    assert len(entries) == 2 * 3 * 3 and len(recipes) == 2 * len(entries)
    assert {(e["kind"], e["family"]) for e in entries} == {
        (k, f) for k in KIND_MEMBERS for f in ("sphere", "torus", "rounded_box")}
    assert len({r["name"] for r in recipes}) == len(recipes)
    for kind in KIND_MEMBERS:  # the colours of a (kind, family) differ
        for family in ("sphere", "torus", "rounded_box"):
            colours = [tuple(e["albedo_linear"]) for e in entries if (e["kind"], e["family"]) == (kind, family)]
            assert len(set(colours)) == 3
    metal_colours = {tuple(e["albedo_linear"]) for e in entries if e["kind"] == "metal"}
    assert metal_colours <= {tuple(v) for v in METAL_F0.values()}


def test_a_pair_differs_only_in_its_property(default_pairs):
    entries, recipes = default_pairs
    by_name = {r["name"]: r for r in recipes}
    for e in entries:
        low, high = (by_name[e["scenes"][m]] for m in KIND_MEMBERS[e["kind"]])
        strip = ("name", "material", "pair")
        assert {k: v for k, v in low.items() if k not in strip} == {k: v for k, v in high.items() if k not in strip}
        differing = {k for k in low["material"] if low["material"][k] != high["material"][k]}
        assert differing == ({"roughness"} if e["kind"] == "roughness" else {"metallic"})
        assert low["material"]["albedo_linear"] == high["material"]["albedo_linear"] == e["albedo_linear"]
        if e["kind"] == "roughness":
            assert (low["material"]["roughness"], high["material"]["roughness"]) == (0.1, 0.8)
            assert low["material"]["metallic"] == high["material"]["metallic"] == 0.0
        else:
            assert (low["material"]["metallic"], high["material"]["metallic"]) == (0.0, 1.0)


def test_pairs_share_no_draw_or_name_with_benchmark_scenes(default_pairs):
    _, recipes = default_pairs
    bench = scene_recipes(0, BenchmarkConfig(num_train_scenes=16, num_val_scenes=2, num_test_scenes=4))
    assert not {r["name"] for r in bench} & {r["name"] for r in recipes}
    assert not {repr(r["shape"]) for r in bench} & {repr(r["shape"]) for r in recipes}
    assert not {r["view_seed"] for r in bench} & {r["view_seed"] for r in recipes}


def test_a_pair_does_not_depend_on_which_others_are_made(default_pairs):
    entries, recipes = default_pairs
    first = next(e for e in entries if (e["kind"], e["family"]) == ("metal", "torus"))  # its colour 0
    full = [r for r in recipes if r["pair"]["id"] == first["id"]]
    alone = controlled_pairs(0, ControlledPairsConfig(kinds=("metal",), families=("torus",), colours=1), **VIEWS)[1]
    assert [r["pair"]["id"] for r in alone] == ["c00", "c00"] != [r["pair"]["id"] for r in full]
    ignore = ("name", "pair", "index")  # the running id only
    assert [{k: v for k, v in r.items() if k not in ignore} for r in alone] == \
        [{k: v for k, v in r.items() if k not in ignore} for r in full]


def test_dataset_holds_the_pairs_as_test_scenes_with_their_manifest(pairs_dir):
    pairs = read_manifest(pairs_dir)
    splits = read_splits(pairs_dir)
    assert splits["train"] == [] and splits["val"] == []
    assert sorted(splits["test"]) == sorted(s for p in pairs for s in p["scenes"].values())
    assert [p["kind"] for p in pairs] == ["roughness", "metal"]


def _maps(scene_dir: Path, name: str) -> list[np.ndarray]:
    scene = read_scene(scene_dir)
    return [read_view_file(scene.view_dir(s, v.id), name) for s, vs in scene.views.items() for v in vs]


def test_gt_maps_of_a_pair_are_identical_but_the_property(pairs_dir):
    for p in read_manifest(pairs_dir):
        low, high = (pairs_dir / p["scenes"][m] for m in KIND_MEMBERS[p["kind"]])
        for name in ("albedo.png", "normal.exr", "depth.exr", "mask.png"):  # same bytes, same object
            for v_low, v_high in zip(_maps(low, name), _maps(high, name)):
                np.testing.assert_array_equal(v_low, v_high)
        masks = _maps(low, "mask.png")
        assert sum(m.sum() for m in masks) > 0
        for channel in ("roughness", "metallic"):
            lows = np.concatenate([m[k[..., 0] > 0.5] for m, k in zip(_maps(low, f"{channel}.png"), masks)])
            highs = np.concatenate([m[k[..., 0] > 0.5] for m, k in zip(_maps(high, f"{channel}.png"), masks)])
            varied = channel == ("roughness" if p["kind"] == "roughness" else "metallic")
            expect_low, expect_high = ((p["values"][m] for m in KIND_MEMBERS[p["kind"]]) if varied
                                       else (0.0 if channel == "metallic" else 0.2,) * 2)
            np.testing.assert_allclose(lows, expect_low, atol=1e-4)
            np.testing.assert_allclose(highs, expect_high, atol=1e-4)
        rgb_low, rgb_high = _maps(low, "rgb.exr"), _maps(high, "rgb.exr")
        assert any(not np.array_equal(a, b) for a, b in zip(rgb_low, rgb_high))  # the photos do differ


def test_same_seed_same_bytes_other_seed_other_scenes(pairs_dir, tmp_path):
    again = tmp_path / "again"
    run(make_config(again))
    assert hashes(again) == hashes(pairs_dir)
    other = tmp_path / "other"
    run(make_config(other, seed=1, extra=["data.controlled_pairs.kinds=[metal]"]))
    gt = read_scene(pairs_dir / read_manifest(pairs_dir)[1]["scenes"]["metal"]).extra["generator"]["shape"]
    assert read_scene(other / read_manifest(other)[0]["scenes"]["metal"]).extra["generator"]["shape"] != gt


@pytest.mark.parametrize("extra, message", [
    (["data.num_test_scenes=4"], "test scenes only"),
    (["data.controlled_pairs.families=[teapot]"], "families"),
    (["data.controlled_pairs.glossy_roughness=0.9"], "below matte_roughness"),
    (["data.controlled_pairs.colours=8"], "colours"),
])
def test_bad_settings_are_refused_before_anything_is_rendered(tmp_path, extra, message):
    with pytest.raises((ValueError, ConfigError), match=message):
        run(make_config(tmp_path / "bad", extra=extra))
    assert not (tmp_path / "bad" / "splits.json").exists()

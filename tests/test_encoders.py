"""Tests of the global prior encoders (gspi/stage2/encoders.py) and their per-scene feature cache
(gspi/stage2/feature_cache.py). Nothing is downloaded: DINOv2 is a tiny random config."""
from __future__ import annotations

import pytest
import torch

from gspi.stage2.encoders import (AlexNetEncoder, NoPriorEncoder, build_encoder, encoder_hash,
                                  lattice_images_srgb)
from gspi.stage2.feature_cache import cache_path, scene_feature_maps, scene_prior_features
from tests.stage2_fixtures import make_lattice_scene


def images(v=2, size=40):
    return torch.rand(v, 3, size, size, generator=torch.Generator().manual_seed(0))


def test_alexnet_shapes_and_layers():
    enc = build_encoder({"encoder": "alexnet", "alexnet": {"layer": "relu5", "input_size": 96}})
    assert isinstance(enc, AlexNetEncoder) and enc.name == "alexnet" and enc.feature_dim == 256
    out = enc.encode(images())
    assert out.shape == (2, 256, 5, 5) and out.dtype == torch.float32 and (out >= 0).all()  # after ReLU
    assert build_encoder({"encoder": "alexnet", "alexnet": {"layer": "relu3", "input_size": 64}}).encode(
        images(1)).shape == (1, 384, 5, 5)
    with pytest.raises(ValueError, match="relu5"):
        build_encoder({"encoder": "alexnet", "alexnet": {"layer": "fc7"}})


def test_alexnet_uses_the_lpips_imagenet_weights():
    from eval.lpips.net import load_lpips

    enc = build_encoder({"encoder": "alexnet"})
    conv1 = enc.net[0][0]
    assert torch.equal(conv1.weight, load_lpips().net.slice1[0].weight)


def test_none_encoder():
    enc = build_encoder({"encoder": "none"})
    assert isinstance(enc, NoPriorEncoder) and enc.feature_dim == 0
    assert enc.encode(images(3)).shape == (3, 0, 5, 5)


def test_unknown_encoder_lists_allowed():
    with pytest.raises(ValueError, match="alexnet, dinov2, none"):
        build_encoder({"encoder": "clip"})


def test_dinov2_missing_directory_is_named(tmp_path):
    missing = tmp_path / "no_such_model"
    with pytest.raises(FileNotFoundError, match="no_such_model"):
        build_encoder({"encoder": "dinov2", "dinov2": {"path": str(missing)}})


def test_dinov2_tiny_random_config_roundtrip(tmp_path):
    transformers = pytest.importorskip("transformers")
    config = transformers.Dinov2Config(hidden_size=32, num_hidden_layers=1, num_attention_heads=2,
                                       intermediate_size=64, patch_size=14, image_size=56)
    torch.manual_seed(0)
    transformers.Dinov2Model(config).save_pretrained(tmp_path / "dino")
    enc = build_encoder({"encoder": "dinov2", "dinov2": {"path": str(tmp_path / "dino"), "input_size": 70}})
    assert enc.name == "dinov2" and enc.feature_dim == 32
    out = enc.encode(images())
    assert out.shape == (2, 32, 5, 5) and torch.isfinite(out).all()
    # patch grid 70 / 14 = 5: pooling to 5x5 is the identity, so cells are the raw patch tokens
    x = torch.nn.functional.interpolate(images(), size=(70, 70), mode="bilinear", antialias=True)
    mean = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
    std = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
    hidden = enc.model(pixel_values=(x - mean) / std).last_hidden_state
    torch.testing.assert_close(out[1, :, 0, 1], hidden[1, 1 + 1])
    with pytest.raises(ValueError, match="patch size"):
        build_encoder({"encoder": "dinov2", "dinov2": {"path": str(tmp_path / "dino"), "input_size": 50}})


class CountingEncoder:
    """A stand-in encoder that counts its calls (cache behaviour only)."""

    name = "counting"
    feature_dim = 4

    def __init__(self):
        self.calls = 0

    def encode(self, imgs):
        self.calls += 1
        return imgs.mean(dim=(2, 3))[:, :1, None, None].expand(-1, self.feature_dim, 5, 5).contiguous()

    def encode_map(self, imgs):
        self.calls += 1
        return imgs[:, :1, ::4, ::4].expand(-1, self.feature_dim, -1, -1).contiguous()  # [V, D, 8, 8]

    def identity(self):
        return {"name": self.name, "dim": self.feature_dim}


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    return make_lattice_scene(tmp_path_factory.mktemp("enc"), "sphere")


def test_lattice_images_are_clamped_srgb(scene_dir):
    imgs = lattice_images_srgb(scene_dir)
    assert imgs.shape == (32, 3, 32, 32) and imgs.min() >= 0 and imgs.max() <= 1


def test_feature_cache_hit_miss_invalid(scene_dir, tmp_path):
    enc = CountingEncoder()
    first = scene_prior_features(scene_dir, enc, tmp_path)
    path = cache_path(tmp_path, "sphere", enc)
    assert path.name == f"counting-{encoder_hash(enc)}.pt" and path.is_file() and enc.calls == 1
    assert first.shape == (32, 4, 5, 5)
    torch.testing.assert_close(scene_prior_features(scene_dir, enc, tmp_path), first)
    assert enc.calls == 1  # hit
    path.write_bytes(b"not a torch file")  # corrupt -> recomputed and rewritten
    torch.testing.assert_close(scene_prior_features(scene_dir, enc, tmp_path), first)
    assert enc.calls == 2
    entry = torch.load(path, weights_only=True)
    torch.save({**entry, "features": entry["features"][:5]}, path)  # wrong shape -> recomputed
    scene_prior_features(scene_dir, enc, tmp_path)
    assert enc.calls == 3
    torch.save({**entry, "features": entry["features"] * float("nan")}, path)  # non-finite -> recomputed
    scene_prior_features(scene_dir, enc, tmp_path)
    assert enc.calls == 4
    torch.save({**entry, "inputs": [["000", 1, 1]]}, path)  # inputs changed -> recomputed
    scene_prior_features(scene_dir, enc, tmp_path)
    assert enc.calls == 5
    other = CountingEncoder()
    other.feature_dim = 6  # another encoder config: another file (miss), the first stays
    assert scene_prior_features(scene_dir, other, tmp_path).shape == (32, 6, 5, 5)
    assert cache_path(tmp_path, "sphere", other) != path and path.is_file()
    scene_prior_features(scene_dir, enc, None)
    assert enc.calls == 6  # no cache dir: always computed


def test_alexnet_scene_features_cached(scene_dir, tmp_path):
    enc = build_encoder({"encoder": "alexnet", "alexnet": {"input_size": 64}})
    feats = scene_prior_features(scene_dir, enc, tmp_path)
    assert feats.shape == (32, 256, 5, 5)
    assert cache_path(tmp_path, "sphere", enc).is_file()


def test_feature_maps_are_cached_beside_the_grid(scene_dir, tmp_path):
    """stage2.data.pixel_features: the unpooled maps get their own file; a stale one is recomputed."""
    enc = CountingEncoder()
    grid = scene_prior_features(scene_dir, enc, tmp_path)
    maps = scene_feature_maps(scene_dir, enc, tmp_path)
    path = cache_path(tmp_path, "sphere", enc, unpooled=True)
    assert path.name == f"counting-{encoder_hash(enc)}-map.pt" and path.is_file()
    assert maps.shape == (32, 4, 8, 8) and grid.shape == (32, 4, 5, 5) and enc.calls == 2
    torch.testing.assert_close(scene_feature_maps(scene_dir, enc, tmp_path), maps)
    torch.testing.assert_close(scene_prior_features(scene_dir, enc, tmp_path), grid)
    assert enc.calls == 2  # both hits
    entry = torch.load(path, weights_only=True)
    torch.save({**entry, "features": entry["features"][:, :2]}, path)  # wrong width -> recomputed
    torch.testing.assert_close(scene_feature_maps(scene_dir, enc, tmp_path), maps)
    assert enc.calls == 3


def test_the_grid_is_the_pooled_map():
    """encode() pools encode_map() to 5 x 5: the pixel features and the global cells are one map."""
    enc = build_encoder({"encoder": "alexnet"})
    maps = enc.encode_map(images())
    assert maps.shape == (2, 256, 13, 13)  # relu5 at 224 px
    torch.testing.assert_close(enc.encode(images()), torch.nn.functional.adaptive_avg_pool2d(maps, 5))
    with pytest.raises(ValueError, match="pixel_features"):
        NoPriorEncoder().encode_map(images())

"""Frozen global semantic prior encoders of Stage II (paper Sec. "Global Semantic Prior":
offline-precomputed features of the V = 32 lattice views, adaptively pooled to a 5 x 5 grid).

One interface (:class:`PriorEncoder`): ``encode(images [V, 3, H, W] in [0, 1]) -> [V, D, 5, 5]``,
plus ``feature_dim`` (D) and ``name``. Built by :func:`build_encoder` from ``stage2.prior``:

* ``alexnet`` (offline default): the ImageNet AlexNet conv trunk shipped with the LPIPS
  weights (``eval.lpips.net.load_lpips().net``, torchvision ``alexnet.features``), layer
  ``relu5`` (D = 256; ``relu3``/``relu4`` = 384/256 also allowed). Input: bilinear (antialiased)
  resize to ``input_size`` (224, AlexNet's training size: relu5 is then 13 x 13), ImageNet
  mean/std normalisation. The paper uses DINOv2; AlexNet is the prior that needs no download.
* ``dinov2``: ``transformers.Dinov2Model.from_pretrained(<local dir>)`` (never downloads),
  ImageNet normalisation, resize to ``input_size`` (a multiple of the patch size), the last
  hidden state's patch tokens (CLS dropped) reshaped to their ``g x g`` grid. D = hidden size.
* ``none``: ablation A1, no global tokens (D = 0; ``encode`` returns [V, 0, 5, 5]).

The images are the lattice views' RGB as the pipeline sees them: linear HDR radiance
(``rgb.exr``) clamped to [0, 1], then sRGB-encoded (:func:`lattice_images_srgb`).
Per-scene caching of the features lives in ``gspi.stage2.feature_cache``.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Mapping, Optional, Protocol

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from gspi.strict_config import dataclass_from_dict

GRID_SIZE = 5  # 5 x 5 pooled cells per view (paper)
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
ENCODERS = ("alexnet", "dinov2", "none")
ALEXNET_LAYERS = {"relu3": (3, 384), "relu4": (4, 256), "relu5": (5, 256)}  # name -> (slices, D)
ENCODER_CACHE_VERSION = 1  # bump when an encoder's preprocessing changes (invalidates caches)


def pool_grid(maps: Tensor) -> Tensor:
    """[V, D, g, g] unpooled encoder maps -> the [V, D, 5, 5] global prior grid (every encoder's
    ``encode`` is this of its ``encode_map``)."""
    return F.adaptive_avg_pool2d(maps, GRID_SIZE)


class PriorEncoder(Protocol):
    """A frozen image encoder producing the 5 x 5 global prior grid of each view."""

    name: str
    feature_dim: int

    def encode(self, images: Tensor) -> Tensor:
        """[V, 3, H, W] sRGB in [0, 1] -> [V, feature_dim, 5, 5] float32 (encode_map, pooled)."""
        ...

    def encode_map(self, images: Tensor) -> Tensor:
        """[V, 3, H, W] sRGB in [0, 1] -> the unpooled [V, feature_dim, g, g] float32 map."""
        ...

    def identity(self) -> dict:
        """JSON-able description of everything that changes the features (the cache key)."""
        ...


def _check_images(images: Tensor) -> Tensor:
    if images.dim() != 4 or images.shape[1] != 3:
        raise ValueError(f"images must be [V, 3, H, W], got {tuple(images.shape)}")
    return images.float().clamp(0.0, 1.0)


def imagenet_normalize(images: Tensor, size: int) -> Tensor:
    """[V, 3, H, W] in [0, 1] -> resized to size x size, (x - mean) / std (ImageNet)."""
    x = F.interpolate(images, size=(size, size), mode="bilinear", align_corners=False, antialias=True)
    mean = torch.tensor(IMAGENET_MEAN, device=x.device).view(1, 3, 1, 1)
    std = torch.tensor(IMAGENET_STD, device=x.device).view(1, 3, 1, 1)
    return (x - mean) / std


class AlexNetEncoder:
    """AlexNet (ImageNet weights of the LPIPS conversion) conv features at ``layer``."""

    name = "alexnet"

    def __init__(self, *, layer: str = "relu5", input_size: int = 224, device: str = "cpu"):
        if layer not in ALEXNET_LAYERS:
            raise ValueError(f"unknown AlexNet layer {layer!r}; allowed: {sorted(ALEXNET_LAYERS)}")
        from eval.lpips.net import load_lpips  # the weights live with the LPIPS network

        self.layer, self.input_size = layer, int(input_size)
        num_slices, self.feature_dim = ALEXNET_LAYERS[layer]
        trunk = load_lpips(device=device).net
        self.net = nn.Sequential(*[getattr(trunk, f"slice{k}") for k in range(1, num_slices + 1)])
        self.device = torch.device(device)

    @torch.no_grad()
    def encode(self, images: Tensor) -> Tensor:
        return pool_grid(self.encode_map(images))

    @torch.no_grad()
    def encode_map(self, images: Tensor) -> Tensor:
        """[V, 3, H, W] -> the unpooled [V, D, g, g] map (13 x 13 for relu3-5 at 224 px)."""
        x = imagenet_normalize(_check_images(images).to(self.device), self.input_size)
        return self.net(x).float().cpu()

    def identity(self) -> dict:
        from eval.lpips import weights as lpips_weights

        return {"name": self.name, "layer": self.layer, "input_size": self.input_size,
                "weights": lpips_weights.weights_path().name, "version": ENCODER_CACHE_VERSION}


class Dinov2Encoder:
    """DINOv2 ViT patch tokens from a LOCAL ``save_pretrained`` directory."""

    name = "dinov2"

    def __init__(self, *, path: str | None, input_size: int = 224, device: str = "cpu"):
        if not path or not Path(path).is_dir():
            raise FileNotFoundError(
                f"DINOv2 model directory {path!r} does not exist: set stage2.prior.dinov2.path to a "
                "local folder written by Dinov2Model.save_pretrained (nothing is downloaded)")
        try:
            from transformers import Dinov2Model
        except ImportError as exc:
            raise ImportError("encoder 'dinov2' needs transformers: pip install -e .[hf]") from exc
        self.path = Path(path)
        self.model = Dinov2Model.from_pretrained(str(self.path), local_files_only=True).eval().to(device)
        self.model.requires_grad_(False)
        self.patch_size = int(self.model.config.patch_size)
        if input_size % self.patch_size:
            raise ValueError(f"dinov2 input_size {input_size} is not a multiple of the patch size {self.patch_size}")
        self.input_size = int(input_size)
        self.feature_dim = int(self.model.config.hidden_size)
        self.device = torch.device(device)

    @torch.no_grad()
    def encode(self, images: Tensor) -> Tensor:
        return pool_grid(self.encode_map(images))

    @torch.no_grad()
    def encode_map(self, images: Tensor) -> Tensor:
        """[V, 3, H, W] -> the patch tokens on their [V, D, g, g] grid (g = input_size / patch)."""
        x = imagenet_normalize(_check_images(images).to(self.device), self.input_size)
        hidden = self.model(pixel_values=x).last_hidden_state  # [V, 1 + g*g, D]
        g = self.input_size // self.patch_size
        patches = hidden[:, -g * g:]  # patch tokens come last (after CLS)
        return patches.transpose(1, 2).reshape(len(x), self.feature_dim, g, g).float().cpu()

    def identity(self) -> dict:
        config_file = self.path / "config.json"
        digest = hashlib.sha256(config_file.read_bytes()).hexdigest()[:16] if config_file.is_file() else None
        weights = sorted((p.name, p.stat().st_size) for p in self.path.iterdir()
                         if p.suffix in (".safetensors", ".bin"))
        return {"name": self.name, "path": str(self.path.resolve()), "config_sha256": digest,
                "weights": weights, "input_size": self.input_size, "version": ENCODER_CACHE_VERSION}


class NoPriorEncoder:
    """Ablation A1: no global semantic prior (zero-width features, no tokens)."""

    name = "none"
    feature_dim = 0

    def encode(self, images: Tensor) -> Tensor:
        return torch.zeros(_check_images(images).shape[0], 0, GRID_SIZE, GRID_SIZE)

    def encode_map(self, images: Tensor) -> Tensor:
        raise ValueError("stage2.data.pixel_features samples the prior encoder's feature map: it needs "
                         "stage2.prior.encoder alexnet or dinov2, not none (A1)")

    def identity(self) -> dict:
        return {"name": self.name, "version": ENCODER_CACHE_VERSION}


@dataclass
class AlexNetOptions:
    layer: str = "relu5"              # 256-dim ImageNet AlexNet conv5 (after ReLU)
    input_size: int = 224

    RANGES: ClassVar[dict] = {"input_size": (32, 4096)}
    CHOICES: ClassVar[dict] = {"layer": tuple(ALEXNET_LAYERS)}


@dataclass
class Dinov2Options:
    path: Optional[str] = None        # local Dinov2Model.save_pretrained folder (never downloaded)
    input_size: int = 224             # multiple of the patch size (14)

    RANGES: ClassVar[dict] = {"input_size": (14, 4096)}


@dataclass
class PriorConfig:
    encoder: str = "alexnet"          # alexnet (offline default) | dinov2 (paper) | none (A1)
    cache_dir: Optional[str] = None   # null = <data>/.cache/stage2_prior
    alexnet: AlexNetOptions = field(default_factory=AlexNetOptions)
    dinov2: Dinov2Options = field(default_factory=Dinov2Options)

    def __post_init__(self) -> None:
        if self.encoder not in ENCODERS:
            raise ValueError(f"unknown stage2.prior.encoder {self.encoder!r}; allowed: {', '.join(ENCODERS)}")


def build_encoder(prior: Mapping[str, Any] | PriorConfig, *, device: str = "cpu") -> PriorEncoder:
    """Factory from the ``stage2.prior`` config (keys ``encoder``, ``alexnet``, ``dinov2``)."""
    if not isinstance(prior, PriorConfig):
        prior = dataclass_from_dict(PriorConfig, prior, "stage2.prior")
    if prior.encoder == "alexnet":
        return AlexNetEncoder(layer=prior.alexnet.layer, input_size=prior.alexnet.input_size, device=device)
    if prior.encoder == "dinov2":
        return Dinov2Encoder(path=prior.dinov2.path, input_size=prior.dinov2.input_size, device=device)
    return NoPriorEncoder()


def encoder_hash(encoder: PriorEncoder) -> str:
    """12 hex digits of sha256 over the encoder's identity (the cache file name's hash)."""
    blob = json.dumps(encoder.identity(), sort_keys=True).encode()
    return hashlib.sha256(blob).hexdigest()[:12]


def lattice_images_srgb(scene_dir: str | Path) -> Tensor:
    """The scene's lattice (train split) views as the encoders see them.

    Returns:
        [V, 3, H, W] float32: ``linear_to_srgb(clamp(rgb.exr, 0, 1))``, in lattice order.
    """
    from eval.common.colorspace import linear_to_srgb
    from eval.common.layout import read_scene, read_view_file

    scene = read_scene(scene_dir)
    images = [read_view_file(scene.view_dir("train", v.id), "rgb.exr") for v in scene.split_views("train")]
    rgb = torch.from_numpy(np.stack(images)).float()  # [V, H, W, 3] linear HDR
    return linear_to_srgb(rgb.clamp(0.0, 1.0)).permute(0, 3, 1, 2).contiguous()

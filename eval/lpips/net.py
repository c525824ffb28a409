"""AlexNet and VGG16 LPIPS v0.1 (Zhang et al., CVPR 2018) in plain torch.

Why hand-written: the reference ``lpips`` package builds its backbone with
``torchvision.models.alexnet(pretrained=True)``, i.e. it needs torchvision (which
does not import in this environment) and downloads the ImageNet weights at run
time. This module re-implements the same network (richzhang/PerceptualSimilarity,
``lpips/lpips.py`` and ``lpips/pretrained_networks.py``, net='alex' or 'vgg',
version='0.1') and loads weights converted once by ``python -m eval.lpips.weights``
(``--net vgg`` for VGG16).

Parameter names follow the reference module (``net.sliceK.I.*``,
``linK.model.1.weight``, ``scaling_layer.*``) so its ``state_dict`` loads here
strictly and vice versa.
"""

from __future__ import annotations

import torch
from torch import nn
import torch.nn.functional as F

ALLOWED_NETS = ("alex", "vgg")
ALLOWED_VERSIONS = ("0.1",)
CHANNELS = (64, 192, 384, 256, 256)  # channels of relu1..relu5 (AlexNet)
NET_CHANNELS = {"alex": CHANNELS, "vgg": (64, 128, 256, 512, 512)}  # VGG: relu1_2 .. relu5_3

_MODEL_CACHE: dict[tuple[str, str], "LPIPS"] = {}


class ScalingLayer(nn.Module):
    """Maps [-1, 1] inputs to the ImageNet-normalised range the backbone expects."""

    def __init__(self) -> None:
        super().__init__()
        self.register_buffer("shift", torch.tensor([-0.030, -0.088, -0.188])[None, :, None, None])
        self.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450])[None, :, None, None])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.shift) / self.scale


def _slice(layers: dict[int, nn.Module]) -> nn.Sequential:
    """Sequential whose child names are torchvision ``features`` indices."""
    seq = nn.Sequential()
    for idx, layer in layers.items():
        seq.add_module(str(idx), layer)
    return seq


class AlexNetFeatures(nn.Module):
    """torchvision AlexNet ``features`` cut into five slices ending at relu1..relu5."""

    def __init__(self) -> None:
        super().__init__()
        relu = lambda: nn.ReLU(inplace=False)  # noqa: E731
        self.slice1 = _slice({0: nn.Conv2d(3, 64, 11, stride=4, padding=2), 1: relu()})
        self.slice2 = _slice({2: nn.MaxPool2d(3, 2), 3: nn.Conv2d(64, 192, 5, padding=2), 4: relu()})
        self.slice3 = _slice({5: nn.MaxPool2d(3, 2), 6: nn.Conv2d(192, 384, 3, padding=1), 7: relu()})
        self.slice4 = _slice({8: nn.Conv2d(384, 256, 3, padding=1), 9: relu()})
        self.slice5 = _slice({10: nn.Conv2d(256, 256, 3, padding=1), 11: relu()})

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        feats = []
        for s in (self.slice1, self.slice2, self.slice3, self.slice4, self.slice5):
            x = s(x)
            feats.append(x)  # B x C_k x H_k x W_k
        return feats


class VGG16Features(nn.Module):
    """torchvision VGG16 ``features`` cut into five slices ending at relu1_2 .. relu5_3."""

    def __init__(self) -> None:
        super().__init__()
        plan = [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512]
        layers, chn, idx = [], 3, 0
        for v in plan:
            if v == "M":
                layers.append((idx, nn.MaxPool2d(2, 2)))
                idx += 1
            else:
                layers += [(idx, nn.Conv2d(chn, v, 3, padding=1)), (idx + 1, nn.ReLU(inplace=False))]
                chn, idx = v, idx + 2
        ends = (4, 9, 16, 23, 30)
        starts = (0,) + ends[:-1]
        for k, (a, b) in enumerate(zip(starts, ends), start=1):
            setattr(self, f"slice{k}", _slice({i: m for i, m in layers if a <= i < b}))

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        feats = []
        for k in range(1, 6):
            x = getattr(self, f"slice{k}")(x)
            feats.append(x)
        return feats


class NetLinLayer(nn.Module):
    """Dropout (identity in eval) + 1x1 conv to one channel, no bias."""

    def __init__(self, chn_in: int) -> None:
        super().__init__()
        self.model = nn.Sequential(nn.Dropout(), nn.Conv2d(chn_in, 1, 1, bias=False))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.model(x)


def normalize_tensor(x: torch.Tensor, eps: float = 1e-10) -> torch.Tensor:
    """Unit-normalise each spatial feature vector over channels (dim 1)."""
    return x / (torch.sqrt(torch.sum(x**2, dim=1, keepdim=True)) + eps)


class LPIPS(nn.Module):
    """LPIPS distance with an AlexNet (default) or VGG16 trunk and v0.1 linear heads.

    Weights are random at construction; use :func:`load_lpips` for the real ones.
    """

    def __init__(self, net: str = "alex") -> None:
        super().__init__()
        if net not in ALLOWED_NETS:
            raise ValueError(f"LPIPS net {net!r} is not supported; allowed: {list(ALLOWED_NETS)}")
        self.net_name = net
        self.scaling_layer = ScalingLayer()
        self.net = AlexNetFeatures() if net == "alex" else VGG16Features()
        for k, c in enumerate(NET_CHANNELS[net]):
            self.add_module(f"lin{k}", NetLinLayer(c))  # reference names lin0..lin4

    @property
    def lins(self) -> list[NetLinLayer]:
        return [getattr(self, f"lin{k}") for k in range(5)]

    def forward(self, x: torch.Tensor, y: torch.Tensor, spatial: bool = False) -> torch.Tensor:
        """Perceptual distance between two image batches.

        Args:
            x: B x 3 x H x W RGB images in [-1, 1].
            y: B x 3 x H x W RGB images in [-1, 1].
            spatial: if True return the per-pixel map instead of its average.

        Returns:
            B x 1 x 1 x 1 distances, or a B x 1 x H x W map if ``spatial``.
        """
        fx = self.net(self.scaling_layer(x))
        fy = self.net(self.scaling_layer(y))
        total = 0
        for lin, a, b in zip(self.lins, fx, fy):
            d = lin((normalize_tensor(a) - normalize_tensor(b)) ** 2)  # B x 1 x H_k x W_k
            if spatial:
                total = total + F.interpolate(d, size=tuple(x.shape[2:]), mode="bilinear", align_corners=False)
            else:
                total = total + d.mean(dim=(2, 3), keepdim=True)
        return total


def load_lpips(net: str = "alex", version: str = "0.1", device: str | torch.device = "cpu") -> LPIPS:
    """Return the pretrained LPIPS network in eval mode with frozen parameters.

    The model is cached per (weights file, device) within the process.

    Args:
        net: backbone, "alex" or "vgg".
        version: linear-head version; only "0.1" is supported.
        device: torch device for the model.

    Raises:
        ValueError: for an unsupported ``net`` or ``version``.
        FileNotFoundError: when the converted weights have not been installed.
    """
    if net not in ALLOWED_NETS:
        raise ValueError(f"LPIPS net {net!r} is not supported; allowed: {list(ALLOWED_NETS)}")
    if version not in ALLOWED_VERSIONS:
        raise ValueError(f"LPIPS version {version!r} is not supported; allowed: {list(ALLOWED_VERSIONS)}")
    from eval.lpips import weights as lpips_weights  # local import: nothing happens at module import

    path = lpips_weights.weights_path(net)
    key = (str(path), str(torch.device(device)))
    if key not in _MODEL_CACHE:
        if not path.is_file():
            raise FileNotFoundError(
                f"LPIPS {net} weights not found at {path}. Install them once with "
                f"`python -m eval.lpips.weights --net {net}` (or `make install`)."
            )
        lpips_weights.verify_converted(path)
        model = LPIPS(net)
        model.load_state_dict(torch.load(path, map_location="cpu", weights_only=True), strict=True)
        model.eval().requires_grad_(False)
        _MODEL_CACHE[key] = model.to(device)
    return _MODEL_CACHE[key]


__all__ = ["LPIPS", "load_lpips", "normalize_tensor", "ALLOWED_NETS", "ALLOWED_VERSIONS"]

"""Structured config of the evaluation protocol (`conf/eval/*.yaml` validates against it).

Every choice a reviewer may question is a field here; docs/PROTOCOL.md explains each default.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from hydra.core.config_store import ConfigStore

from eval.common.errors import StatedError



@dataclass
class LpipsConfig:
    net: str = "alex"            # alex | vgg (PerceptualSimilarity backbones, v0.1 heads)
    version: str = "0.1"         # linear-head version of PerceptualSimilarity
    mode: str = "masked_mean"    # masked_mean | composite (see eval/metrics.py)
    normalize: bool = True       # inputs [0,1] -> [-1,1]; false = GS-IR/IRGS scripts' [0,1] input
    encode_srgb: bool = False    # sRGB-encode albedo/relight images before LPIPS (Stanford-ORB)
    albedo_space: str | None = None  # albedo space LPIPS reads; None = the protocol's albedo_space


@dataclass
class PsnrConfig:
    region: str = "mask"         # mask: MSE over GT-mask pixels | image: whole mask-multiplied image
    mse_floor: float = 1.9403145770321738e-11  # (1/65535)^2/12 (16-bit quantisation): cap 107.12 dB
    grey_floor: bool = False     # Stanford-ORB: PSNR >= that of a constant 0.5 prediction
    channel_mean: bool = False   # mean of per-channel PSNRs (GS-IR, IRGS) instead of one MSE
    map_pooling: str = "view"    # view: one PSNR per map | scene: one MSE pooled over a scene's views (TensoIR albedo)
    albedo_space: str | None = None  # albedo space PSNR reads; None = the protocol's albedo_space


@dataclass
class SsimConfig:
    window: int = 11             # Gaussian window side (sigma 1.5); Stanford-ORB uses 3
    region: str = "mask"         # mask: map averaged in the mask | image: over the whole image
    padding: str = "valid"       # valid: where the window fits (scikit-image) | same: kornia's
                                 # reflection padding (Stanford-ORB) | zero: zero padded (3DGS ssim)
    albedo_space: str | None = None  # albedo space SSIM reads; None = the protocol's albedo_space


@dataclass
class MetallicConfig:
    extra_metrics: bool = True   # also MAE and metal-mask IoU on scenes whose GT has metal
    threshold: float = 0.5       # a pixel is metal when metallic > threshold (IoU)


@dataclass
class RelightConfig:
    envs: list[str] | None = None       # None = the scene's held-out relight_envs
    tonemap: str = "aces"               # aces | clamp | reinhard | none (linear, clipped to hdr_max)
    exposure_stops: float = 0.0         # 2**stops before the tone curve
    srgb: bool = True                   # sRGB-encode after the tone curve
    # A method that does not model a channel is relit with this constant (stated per table).
    fill_roughness: float = 1.0
    fill_metallic: float = 0.0
    apply_albedo_alignment: bool = True  # relight with the aligned albedo when aligning
    clamp_albedo: bool = True           # the aligned albedo relit is clamped to [0, 1] (TensoIR: not)
    scale_fit: str = "none"             # none | lstsq: per-image per-channel scale of the relit
                                        # linear prediction (Stanford-ORB `scale_invariant`)
    reference: str = "shaded"           # shaded: split-sum shading of the GT maps | stored: the scene's
                                        # relit_<env>.exr (data.relit_renderer=pathtraced: shadows too)
    psnr_hdr: bool = False              # also PSNR-H on linear HDR (Stanford-ORB), metric psnr_h
    hdr_max: float = 4.0                # PSNR-H: both images clipped to [0, hdr_max]
    hdr_gt_renorm: bool = True          # PSNR-H: Stanford-ORB's brightness renormalisation of GT


@dataclass
class ProtocolConfig:
    name: str = "gspi-decoupled"
    version: int = 1
    split: str = "test"                 # scored views: test | lattice (= train) | val
    channels: list[str] = field(default_factory=lambda: ["albedo", "roughness", "metallic",
                                                         "relight"])
    background: float = 0.0             # composite value outside the mask for SSIM/LPIPS
    albedo_alignment: str = "none"      # none | scale | lstsq (= per_channel) | median_ratio
    alignment_scope: str = "scene"      # scene (pooled over its views) | view
    albedo_space: str = "srgb"          # colour space albedo is scored in: srgb | linear | linear_gamma22 | gamma22
    alignment_space: str = "linear"     # values the albedo scale is fitted and applied on: linear
                                        # (decoded sRGB) | stored (the file's values: TensoIR, GS-IR, IRGS)
    alignment_pixels: str = "mask"      # mask | mask_positive_gt (IRGS: GT > 0 in every channel too)
    alignment_sampled_views: int | None = None  # None: every view; k: views i * (n // k), i < k (TensoIR: 20)
    albedo_clamp: bool = True           # clamp the aligned albedo to [0, 1] (GS-IR, IRGS: no)
    mask_prediction: bool = True        # prediction composited on `background` outside the GT mask
                                        # (False: scored as it is there, GS-IR)
    mask_erosion_px: int = 0            # erode the GT mask by a (2r+1)^2 square (Stanford-ORB: 2)
    outside_brdf: str = "include"       # include | exclude: the GT's outside_brdf.png pixels (a glTF
                                        # BLEND / KHR_materials_* surface) scored, or left out of the mask
    unpremultiply: bool = False         # divide maps by the prediction's alpha.png inside the mask
    fail_on_missing_view: bool = False  # False: report missing views and score the rest
    psnr: PsnrConfig = field(default_factory=PsnrConfig)
    ssim: SsimConfig = field(default_factory=SsimConfig)
    lpips: LpipsConfig = field(default_factory=LpipsConfig)
    metallic: MetallicConfig = field(default_factory=MetallicConfig)
    relight: RelightConfig = field(default_factory=RelightConfig)


ALIGNMENTS = ("none", "scale", "lstsq", "per_channel", "median_ratio")  # per_channel = lstsq
SCOPES = ("scene", "view")
OUTSIDE_BRDF = ("include", "exclude")
RELIT_REFERENCES = ("shaded", "stored")
CHANNELS = ("albedo", "roughness", "metallic", "relight")
ALBEDO_SPACES = ("srgb", "linear", "linear_gamma22", "gamma22")
ALIGNMENT_SPACES = ("linear", "stored")
ALIGNMENT_PIXELS = ("mask", "mask_positive_gt")
MAP_POOLINGS = ("view", "scene")
SSIM_PADDINGS = ("valid", "same", "zero")
REGIONS = ("mask", "image")
LPIPS_NETS = ("alex", "vgg")
LPIPS_MODES = ("masked_mean", "composite")
TONEMAPS = ("aces", "clamp", "reinhard", "none")
SCALE_FITS = ("none", "lstsq")
SCORED_SPLITS = ("test", "lattice", "train", "val")  # lattice = train (protocol_id.ALIASES)


class ProtocolError(StatedError, ValueError):
    """A protocol value (``eval.<key>``) that is not allowed: the message names the key and the allowed values."""


def _allowed(key: str, value, allowed: tuple) -> None:
    if value not in allowed:
        raise ProtocolError(f"eval.{key}={value!r}; allowed: {', '.join(map(str, allowed))}")


def validate_protocol(cfg) -> None:
    """Raise :class:`ProtocolError` naming the field (and the allowed values) when a value is not allowed."""
    _allowed("albedo_alignment", cfg.albedo_alignment, ALIGNMENTS)
    _allowed("alignment_scope", cfg.alignment_scope, SCOPES)
    _allowed("albedo_space", cfg.albedo_space, ALBEDO_SPACES)
    _allowed("psnr.region", cfg.psnr.region, REGIONS)
    _allowed("ssim.region", cfg.ssim.region, REGIONS)
    _allowed("ssim.padding", cfg.ssim.padding, SSIM_PADDINGS)
    _allowed("alignment_space", cfg.alignment_space, ALIGNMENT_SPACES)
    _allowed("alignment_pixels", cfg.alignment_pixels, ALIGNMENT_PIXELS)
    _allowed("psnr.map_pooling", cfg.psnr.map_pooling, MAP_POOLINGS)
    for metric in ("psnr", "ssim", "lpips"):
        _allowed(f"{metric}.albedo_space", getattr(cfg, metric).albedo_space, (None, *ALBEDO_SPACES))
    k = cfg.alignment_sampled_views
    if k is not None and (isinstance(k, bool) or not isinstance(k, int) or k < 1):
        raise ProtocolError(f"eval.alignment_sampled_views={k!r}: must be null or an integer >= 1")
    if cfg.psnr.map_pooling == "scene" and cfg.psnr.grey_floor:
        raise ProtocolError("eval.psnr.grey_floor applies to one image's PSNR; it cannot be combined "
                         "with eval.psnr.map_pooling=scene")
    _allowed("lpips.net", cfg.lpips.net, LPIPS_NETS)
    _allowed("lpips.version", str(cfg.lpips.version), ("0.1",))
    _allowed("lpips.mode", cfg.lpips.mode, LPIPS_MODES)
    _allowed("relight.tonemap", cfg.relight.tonemap, TONEMAPS)
    _allowed("relight.scale_fit", cfg.relight.scale_fit, SCALE_FITS)
    _allowed("relight.reference", cfg.relight.reference, RELIT_REFERENCES)
    bad = [c for c in cfg.channels if c not in CHANNELS]
    if bad:
        raise ProtocolError(f"eval.channels has unknown {bad}; allowed: {', '.join(CHANNELS)}")
    if not cfg.channels:  # would score nothing and exit 0 with an empty summary
        raise ProtocolError(f"eval.channels=[]: must name at least one of {CHANNELS}")
    # the composite value outside the mask enters SSIM and LPIPS: a display value in [0, 1]
    background = cfg.background
    if isinstance(background, bool) or not isinstance(background, (int, float)) or not 0.0 <= background <= 1.0:
        raise ProtocolError(f"eval.background={background!r}: must be a number in [0, 1]")
    if isinstance(cfg.version, bool) or not isinstance(cfg.version, int) or cfg.version < 1:
        raise ProtocolError(f"eval.version={cfg.version!r}: must be an integer >= 1")
    _allowed("split", cfg.split, SCORED_SPLITS)
    _allowed("unpremultiply", cfg.unpremultiply, (False, True))
    if not float(cfg.psnr.mse_floor) > 0:
        raise ProtocolError(f"eval.psnr.mse_floor={cfg.psnr.mse_floor}: must be > 0 "
                         "(a zero floor lets one exact image make a mean +inf)")
    if int(cfg.ssim.window) < 1 or int(cfg.ssim.window) % 2 == 0:
        raise ProtocolError(f"eval.ssim.window={cfg.ssim.window}: must be an odd number >= 1")
    _allowed("outside_brdf", cfg.outside_brdf, OUTSIDE_BRDF)
    if int(cfg.mask_erosion_px) < 0:
        raise ProtocolError(f"eval.mask_erosion_px={cfg.mask_erosion_px}: must be >= 0")
    if not float(cfg.relight.hdr_max) > 0:
        raise ProtocolError(f"eval.relight.hdr_max={cfg.relight.hdr_max}: must be > 0")


def register_configs() -> None:
    ConfigStore.instance().store(group="eval", name="base_eval", node=ProtocolConfig)

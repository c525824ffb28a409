"""Record what TensoIR's, GS-IR's, IRGS's and R3DG's own evaluation code answers on the preset fixtures,
once, as goldens (tests/golden/preset_<project>.json; tests/test_preset_goldens.py compares the
`eval=tensoir|gs_ir|irgs|r3dg` presets with them on every commit).

Each project's code is run **unchanged** from a checkout at the commit named below (outside this
repository: none of it is copied here). Functions (``rgb_ssim``, ``rgb_lpips``, 3DGS ``psnr`` /
``ssim``, ``lpipsPyTorch.lpips``, ``linear2srgb_torch``, ``rgb_to_srgb``) are imported or taken
from their file by name; statements that live inline in an evaluation loop are executed from
their file by line range, after the file's sha256 is checked, with the loop's variables bound to
the fixture (tests/preset_fixtures.py). Only what reads files from disk or renders a model is
replaced by the fixture's arrays; ``Tensor.cuda`` is the identity (CPU). LPIPS is the official
``lpips`` package (and IRGS's own ``lpipsPyTorch``) with the PerceptualSimilarity weights that
eval.lpips.weights installs, handed to torchvision/torch.hub through a temporary TORCH_HOME
(no download).

    git clone https://github.com/Haian-Jin/TensoIR /tmp/ext/tensoir   # at 8f7b8dd
    git clone https://github.com/lzhnb/GS-IR /tmp/ext/gs-ir            # at e5a030b
    git clone https://github.com/fudan-zvg/IRGS /tmp/ext/irgs          # at 1461869
    git clone https://github.com/NJU-3DV/Relightable3DGaussian /tmp/ext/r3dg  # at a102f14
    python -m pip install --target /tmp/oracle --no-deps lpips torchvision==0.29.1 opencv-python-headless
    PYTHONPATH=/tmp/oracle:. python -m tests.golden.record_presets tensoir=/tmp/ext/tensoir \\
        gs_ir=/tmp/ext/gs-ir irgs=/tmp/ext/irgs r3dg=/tmp/ext/r3dg

(recorded with lpips 0.1.4, torchvision 0.29.1 on torch 2.13.0+cpu; each golden names its
producer.) Each project runs in its own process: the three define different top-level `utils`.
"""
from __future__ import annotations

import ast
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import textwrap
import types
from pathlib import Path

import numpy as np
import torch

GOLDEN = Path(__file__).parent
PROJECTS = {  # name -> (repository, commit, {file: sha256})
    "tensoir": ("Haian-Jin/TensoIR", "8f7b8dd", {
        "renderer.py": "a86dda3172330998e5653cf321e4e9a5b3bfa47e84b8c0f0148c53eedb55373c",
        "utils.py": "fb1cbd3970e85f9caf12f9f5e9ca379fabf3fdba73db6ac7d3631dd0e901d0d3",
        "scripts/relight_importance.py": "f4dadc0f895aa669d78aa9b8d5a1ab1054966c3677c082f5a93c3600ed97a27c",
        "models/relight_utils.py": "77ab2323a2409024b4e7432dada835d3722854232dbf71fc2fda398199d2606f"}),
    "gs_ir": ("lzhnb/GS-IR", "e5a030b", {
        "render.py": "cbe6cb597d2cf5a4177daf6c39dfe278974b46e50adfd04591088a85665e7e01",
        "relight_eval.py": "603f4f308e95762877e2b2fde95640500474e9abf08220b3182fdb7911538ff6",
        "pbr/shade.py": "283a1f971e83806d4860e8488a261cee01b48631e388dc1ccf83900b6e0610fe"}),
    "irgs": ("fudan-zvg/IRGS", "1461869", {
        "compute_albedo_scale_tensoir.py": "d78501d36b711df18534d39b69552a4cc4b6768e0a7267a479ca40bfaddd7777",
        "eval_material_tensoir.py": "5ab8fbc08900a2a801349abc48b8fe5361f073302ac35b0e0c1439551e70fec9",
        "eval_relighting_tensoir.py": "4176bc4aa202f4b6d03672ae2da13c2611254839ff9d8c44987fe0104a91768f",
        "gaussian_renderer/__init__.py": "7a41b99a7ec6504fe0891572d1b1f059adcd83cbc8f8ee106ed36b5e4c54b45f"}),
    "r3dg": ("NJU-3DV/Relightable3DGaussian", "a102f14", {
        "eval_relighting_syn4.py": "31404f533fa7b9e869eefc38c3d70e3c9ad4b06c22646593ff46a851f4780de4",
        "utils/image_utils.py": "f7afb88642756eeb8ae84b7c11c0108b35f57c98250cec1a05f6aecb34dc2efc",
        "utils/loss_utils.py": "4d6e8d876eb05b02514b2ab5f040bc2d78b4da25f2e3e66e88507c3598c4092d"}),
}


def golden_path(project: str) -> Path:
    return GOLDEN / f"preset_{project}.json"


# ---- running their code ------------------------------------------------------------------------

class Source:
    """One file of a project's checkout, checked against its recorded sha256."""

    def __init__(self, root: Path, rel: str, sha: str):
        self.path = root / rel
        text = self.path.read_bytes()
        if hashlib.sha256(text).hexdigest() != sha:
            raise SystemExit(f"{self.path}: not the file of the recorded commit (sha256 differs)")
        self.lines = text.decode().splitlines()

    def run(self, first: int, last: int, ns: dict, skip: tuple[int, ...] = ()) -> dict:
        """Execute lines first..last (1-based, inclusive; ``skip`` left out) in ``ns``."""
        code = "\n".join(line for i, line in enumerate(self.lines[first - 1:last], first) if i not in skip)
        exec(compile(textwrap.dedent(code), f"{self.path}:{first}-{last}", "exec"), ns)
        return ns

    def function(self, name: str, ns: dict):
        """Define the file's top-level function ``name`` in ``ns`` and return it."""
        tree = ast.parse("\n".join(self.lines))
        node = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == name)
        exec(compile(ast.get_source_segment("\n".join(self.lines), node), str(self.path), "exec"), ns)
        return ns[name]


def _cpu_cuda() -> None:
    torch.Tensor.cuda = lambda self, *a, **k: self  # their scripts call .cuda(); this runs on the CPU
    torch.nn.Module.cuda = lambda self, *a, **k: self


def _import_torchvision_without_ops() -> None:
    from tests.golden.record_oracles import _import_torchvision_without_ops as skip_ops
    skip_ops()


def _torch_home_with_weights(home: Path) -> None:
    """torchvision's VGG16 / AlexNet ImageNet files and PerceptualSimilarity's v0.1 heads under
    ``home``/hub/checkpoints, from eval.lpips.weights' converted weights (torch.hub checks a
    file's hash only when it downloads it)."""
    from eval.lpips.net import load_lpips

    ckpt = home / "hub" / "checkpoints"
    ckpt.mkdir(parents=True, exist_ok=True)
    import torchvision
    for net, ctor, fname in (("vgg", torchvision.models.vgg16, "vgg16-397923af.pth"),
                             ("alex", torchvision.models.alexnet, "alexnet-owt-7be5be79.pth")):
        ours = load_lpips(net).state_dict()
        full = ctor().state_dict()  # classifier kept at its (unused) init
        for key, value in ours.items():
            if key.startswith("net.slice"):
                full[f"features.{key.split('.')[2]}.{key.split('.')[3]}"] = value
        torch.save(full, ckpt / fname)
        heads = {f"lin{k}.model.1.weight": ours[f"lin{k}.model.1.weight"] for k in range(5)}
        torch.save(heads, ckpt / f"{net}.pth")
    os.environ["TORCH_HOME"] = str(home)


def _lpips_package(net: str):
    import lpips
    return lpips.LPIPS(net=net, version="0.1", verbose=False).eval()


def _row(psnr, ssim, lpips) -> dict:
    return {"psnr": float(psnr), "ssim": float(ssim), "lpips": float(lpips)}


def albedo_as_linear(case: dict) -> dict:
    """A fixture's albedo maps as TensoIR's data holds them: its albedo.png values are linear
    (gspi stores their sRGB encoding, gspi/data/layouts/tensoir.py), and so are the albedo maps
    its, GS-IR's and IRGS's models render; these projects' code is handed these values."""
    from eval.common.colorspace import srgb_to_linear

    return {**case, "gt": [srgb_to_linear(g) for g in case["gt"]], "pred": [srgb_to_linear(p) for p in case["pred"]]}


def _albedo_case(views: list[dict], ratio) -> dict:
    """A case's albedo record: the per-view rows, their means and the fitted scale."""
    scene = {k: float(np.mean([r[k] for r in views])) for k in ("psnr", "ssim", "lpips")}
    return {"views": views, "scene": scene | {"ratio": [float(x) for x in ratio]}}


# ---- TensoIR -------------------------------------------------------------------------------------

def record_tensoir(root: Path) -> dict:
    from tests.preset_fixtures import CASES, HEIGHT as H, RELIT_ENVS, WIDTH as W, albedo_case, relit_case

    files = {rel: Source(root, rel, sha) for rel, sha in PROJECTS["tensoir"][2].items()}
    sys.path.insert(0, str(root))
    import utils as tensoir_utils  # rgb_ssim, rgb_lpips (their module, unchanged)

    tensoir_utils.__LPIPS__.update({n: _lpips_package(n) for n in ("alex", "vgg")})
    helpers = {"torch": torch, "np": np, "logger": types.SimpleNamespace(debug=lambda *a: None)}
    files["models/relight_utils.py"].function("_clip_0to1_warn_torch", helpers)
    linear2srgb_torch = files["models/relight_utils.py"].function("linear2srgb_torch", helpers)
    renderer, relight = files["renderer.py"], files["scripts/relight_importance.py"]
    device = types.SimpleNamespace(device="cpu")
    out = {"albedo": {}, "relight": {}}
    for case in CASES:
        c = albedo_as_linear(albedo_case(case))
        n = len(c["gt"])
        # dataset: albedo RGBA blended on white (dataLoader/tensoIR_relighting_test.py); float32
        gts = [(g * m[..., None] + (1 - m[..., None].double())).float() for g, m in zip(c["gt"], c["mask"])]
        preds = [p.float() for p in c["pred"]]
        ns = {"torch": torch, "np": np, "data_num": n, "sampled_num": 20, "H": H, "W": W}
        renderer.run(23, 27, ns)                   # compute_rescale_ratio: idx_list, the lists
        for idx in ns["idx_list"]:
            ns.update(gt_albedo=gts[idx].reshape(-1, 3), gt_mask=c["mask"][idx].reshape(-1), albedo_map=preds[idx])
            renderer.run(42, 45, ns)
        renderer.run(47, 50, ns)                   # the pooled ratios
        ns.update(test_all=True, global_rescale_value_single=ns["single_channel_ratio"],
                  global_rescale_value_three=ns["three_channel_ratio"], rgb_ssim=tensoir_utils.rgb_ssim,
                  rgb_lpips=tensoir_utils.rgb_lpips, tensoIR=device)
        renderer.run(156, 156, ns)                 # the map lists
        views = []
        for v in range(n):
            ns.update(albedo_map=preds[v], albedo_gt=gts[v].reshape(-1, 3), gt_mask=c["mask"][v].reshape(-1))
            renderer.run(274, 289, ns)             # aligned maps (ones outside the mask)
            renderer.run(319, 321, ns)             # three-channel aligned: SSIM, LPIPS alex / vgg
            renderer.run(392, 394, ns)             # x^(1/2.2) copies for the PSNR
            views.append({"ssim": float(ns["ssim_albedo_three"]), "lpips_vgg": float(ns["l_v_albedo_three"]),
                          "lpips_alex": float(ns["l_a_albedo_three"])})
        renderer.run(462, 468, ns)                 # albedo PSNR: one MSE over the stacked views
        out["albedo"][case] = {"views": views, "scene": {
            "psnr": float(ns["PSNR_albedo_three"]), "ssim": float(np.mean([r["ssim"] for r in views])),
            "lpips": float(np.mean([r["lpips_vgg"] for r in views])),
            "ratio": [float(x) for x in ns["three_channel_ratio"]]}}

        r = relit_case(case)
        rows = []
        for v in range(n):
            m = r["mask"][v].reshape(-1)
            env_rows = []
            for e, _ in enumerate(RELIT_ENVS):
                ns = {"torch": torch, "np": np, "linear2srgb_torch": linear2srgb_torch, "H": H, "W": W,
                      "surface_relight_rgb_chunk": r["pred"][v][e].float().reshape(-1, 3)[m],
                      "relight_rgb_chunk": torch.zeros(H * W, 3), "acc_chunk_mask": m,
                      "bg_color": torch.zeros(H * W, 3), "rgb_ssim": tensoir_utils.rgb_ssim,
                      "rgb_lpips": tensoir_utils.rgb_lpips, "tensoIR": device, "light_name_idx": 0}
                relight.run(167, 171, ns)          # clamp, linear2srgb, into the image
                relight.run(176, 176, ns)
                relight.run(178, 178, ns)          # white outside the mask
                ns["relight_pred_img_without_bg"] = {"env": [ns["relight_without_bg"]]}
                ns["cur_light_name"] = "env"
                # GT: the dataset's relit PNG, blended on white: clamp + sRGB of the linear GT
                gt_display = linear2srgb_torch(r["gt"][v][e].float().clamp(0, 1))
                ns["gt_rgb"] = [torch.where(r["mask"][v][..., None], gt_display, torch.ones_like(gt_display))]
                relight.run(206, 206, ns)
                relight.run(214, 221, ns)          # per-image PSNR, SSIM, LPIPS alex / vgg
                env_rows.append(_row(ns["cur_psnr"], ns["ssim_relight"], ns["l_v_relight"]))
            rows.append(env_rows)
        out["relight"][case] = {"views": rows}
    return out


# ---- GS-IR ---------------------------------------------------------------------------------------

def record_gs_ir(root: Path) -> dict:
    from tests.preset_fixtures import CASES, RELIT_ENVS, albedo_case, relit_case

    files = {rel: Source(root, rel, sha) for rel, sha in PROJECTS["gs_ir"][2].items()}
    sys.path.insert(0, str(root))
    from utils.image_utils import psnr as get_psnr  # 3DGS utils, unchanged
    from utils.loss_utils import ssim as get_ssim

    shade = files["pbr/shade.py"]
    import typing
    linear_to_srgb = shade.function("linear_to_srgb", {"torch": torch, "np": np, "Union": typing.Union})
    lpips_fn = _lpips_package("vgg")  # render.py:319 LPIPS(net="vgg")
    render, relight = files["render.py"], files["relight_eval.py"]
    out = {"albedo": {}, "relight": {}}
    for case in CASES:
        c = albedo_as_linear(albedo_case(case))
        ns = {"torch": torch, "tqdm": lambda x, **k: x, "get_psnr": get_psnr, "get_ssim": get_ssim,
              "lpips_fn": lpips_fn, "albedo_gts": [], "albedo_maps": [], "masks": [],
              "gt_albedo_list": [], "reconstructed_albedo_list": []}
        for g, p, m in zip(c["gt"], c["pred"], c["mask"]):  # the PNG's values / 255 (linear), as read
            ns.update(albedo_gt=g.float(), albedo_map=p.float().clone(), mask=m)
            render.run(326, 326, ns)
            render.run(328, 329, ns)
            render.run(335, 336, ns)
        render.run(337, 340, ns)                   # the pooled three-channel median ratio
        views, all_views = [], (ns["masks"], ns["albedo_maps"], ns["albedo_gts"])
        for v in range(len(c["gt"])):              # the loop of render.py:342-349, one view at a time
            ns.update(masks=[all_views[0][v]], albedo_maps=[all_views[1][v]], albedo_gts=[all_views[2][v]],
                      albedo_psnr_avg=0.0, albedo_ssim_avg=0.0, albedo_lpips_avg=0.0)
            render.run(342, 349, ns, skip=(346,))  # 346 writes a PNG
            views.append(_row(ns["albedo_psnr_avg"], ns["albedo_ssim_avg"], ns["albedo_lpips_avg"]))
        out["albedo"][case] = _albedo_case(views, ns["three_channel_ratio"])

        r = relit_case(case)
        rows = []
        for v in range(len(r["gt"])):
            m = r["mask"][v][None].float()
            env_rows = []
            for e, _ in enumerate(RELIT_ENVS):
                # relight.py:156-157: clamp(sRGB(shaded)) * alpha; the GT PNG: sRGB of the linear GT
                pred = linear_to_srgb(r["pred"][v][e].float()).clamp(0.0, 1.0).permute(2, 0, 1) * m
                gt = linear_to_srgb(r["gt"][v][e].float().clamp(0.0, 1.0)).permute(2, 0, 1)
                ns = {"get_psnr": get_psnr, "get_ssim": get_ssim, "lpips_fn": lpips_fn, "prediction": pred,
                      "gt_img": gt, "psnr_avg": 0.0, "ssim_avg": 0.0, "lpips_avg": 0.0}
                relight.run(38, 40, ns)
                env_rows.append(_row(ns["psnr_avg"], ns["ssim_avg"], ns["lpips_avg"]))
            rows.append(env_rows)
        out["relight"][case] = {"views": rows}
    return out


# ---- IRGS ----------------------------------------------------------------------------------------

def record_irgs(root: Path) -> dict:
    from tests.preset_fixtures import CASES, RELIT_ENVS, albedo_case, relit_case

    files = {rel: Source(root, rel, sha) for rel, sha in PROJECTS["irgs"][2].items()}
    sys.path.insert(0, str(root))
    from lpipsPyTorch import lpips  # IRGS's own LPIPS (torchvision VGG16 + PerceptualSimilarity heads)
    from utils.graphics_utils import rgb_to_srgb
    from utils.image_utils import psnr
    from utils.loss_utils import ssim

    scale_src, material, relight = (files["compute_albedo_scale_tensoir.py"], files["eval_material_tensoir.py"],
                                    files["eval_relighting_tensoir.py"])
    renderer = files["gaussian_renderer/__init__.py"]
    out = {"albedo": {}, "relight": {}}
    for case in CASES:
        c = albedo_as_linear(albedo_case(case))  # load_img_rgb of TensoIR's albedo.png: linear values
        rgba = [torch.cat([g, m[..., None].double()], -1).numpy() for g, m in zip(c["gt"], c["mask"])]
        raw = [p.float().permute(2, 0, 1) for p in c["pred"]]  # the rendered linear base colour
        ns = {"torch": torch, "albedo_gt_list": [], "albedo_list": []}
        for g_np, p in zip(rgba, raw):
            ns.update(gt_albedo_np=g_np, render_pkg={"base_color_linear": p})
            scale_src.run(87, 89, ns)
            scale_src.run(102, 103, ns)
        scale_src.run(105, 111, ns)                # the scales file: mode 2 = per-channel median
        base_color_scale = torch.tensor(ns["albedo_scale_json"]["2"], dtype=torch.float32)
        views = []
        for g_np, p in zip(rgba, raw):
            rns = {"rendered_base_color": p, "base_color_scale": base_color_scale}
            renderer.run(174, 175, rns)            # render_ir: base colour times the scale
            ns = {"torch": torch, "psnr": psnr, "ssim": ssim, "lpips": lpips, "gt_albedo_np": g_np,
                  "render_pkg": {"base_color_linear": rns["rendered_base_color"]},
                  "args": types.SimpleNamespace(no_lpips=False),
                  "psnr_albedo": 0.0, "ssim_albedo": 0.0, "lpips_albedo": 0.0}
            material.run(107, 108, ns)
            material.run(121, 127, ns)
            views.append(_row(ns["psnr_albedo"], ns["ssim_albedo"], ns["lpips_albedo"]))
        out["albedo"][case] = _albedo_case(views, base_color_scale)

        r = relit_case(case)
        rows = []
        for v in range(len(r["gt"])):
            env_rows = []
            for e, _ in enumerate(RELIT_ENVS):
                gt_display = rgb_to_srgb(r["gt"][v][e].float())  # the GT PNG (clipped sRGB)
                image_rgba = torch.cat([gt_display, r["mask"][v][..., None].float()], -1).numpy()
                ns = {"torch": torch, "psnr": psnr, "ssim": ssim, "lpips": lpips, "image_rgba": image_rgba,
                      "bg": 0, "args": types.SimpleNamespace(no_lpips=False),
                      # render_ir: rgb_to_srgb of the shaded linear radiance
                      "render_pkg": {"render": rgb_to_srgb(r["pred"][v][e].float().permute(2, 0, 1))},
                      "psnr_pbr": 0.0, "ssim_pbr": 0.0, "lpips_pbr": 0.0}
                relight.run(147, 151, ns)
                relight.run(164, 164, ns)
                relight.run(172, 176, ns)
                env_rows.append(_row(ns["psnr_pbr"], ns["ssim_pbr"], ns["lpips_pbr"]))
            rows.append(env_rows)
        out["relight"][case] = {"views": rows}
    return out


# ---- Relightable 3D Gaussian ---------------------------------------------------------------------

def record_r3dg(root: Path) -> dict:
    """eval_relighting_syn4.py: albedo and relit images per view, both composited on the
    background (0: run_syn4.sh trains without -w); no alignment (its per-scene base-colour
    scales are constants of the script, applied inside the model before rendering)."""
    from tests.preset_fixtures import CASES, RELIT_ENVS, albedo_case, relit_case

    files = {rel: Source(root, rel, sha) for rel, sha in PROJECTS["r3dg"][2].items()}
    sys.path.insert(0, str(root))
    from lpipsPyTorch import lpips
    from utils.image_utils import psnr
    from utils.loss_utils import ssim

    from eval.common.colorspace import linear_to_srgb

    ev = files["eval_relighting_syn4.py"]
    out = {"albedo": {}, "relight": {}}
    for case in CASES:
        c, r = albedo_case(case), relit_case(case)
        albedo_rows, relit_rows = [], []
        for v in range(len(c["gt"])):
            env_rows = []
            for e, _ in enumerate(RELIT_ENVS):
                # the relit GT PNG and the rendered images: clamp + sRGB display (eval.common.colorspace)
                gt_display = linear_to_srgb(r["gt"][v][e].float())
                ns = {"torch": torch, "psnr": psnr, "ssim": ssim, "lpips": lpips, "bg": 0,
                      "image": gt_display.numpy(), "mask": r["mask"][v][..., None].float().numpy(),
                      "capture_list": ["base_color", "pbr"],
                      "render_pkg": {"pbr": linear_to_srgb(r["pred"][v][e].float()).permute(2, 0, 1),
                                     "base_color": c["pred"][v].float().permute(2, 0, 1)},
                      "albedo_rgba": torch.cat([c["gt"][v], c["mask"][v][..., None].double()], -1).numpy(),
                      "psnr_pbr": 0.0, "ssim_pbr": 0.0, "lpips_pbr": 0.0,
                      "psnr_albedo": 0.0, "ssim_albedo": 0.0, "lpips_albedo": 0.0}
                ev.run(144, 145, ns)               # GT image and mask tensors
                ev.run(157, 169, ns)               # captures composited on bg (170 writes PNGs)
                ev.run(172, 172, ns)
                ev.run(176, 177, ns)               # GT albedo composited on bg
                ev.run(189, 196, ns)               # PSNR / SSIM / LPIPS of pbr and base colour
                env_rows.append(_row(ns["psnr_pbr"], ns["ssim_pbr"], ns["lpips_pbr"]))
            albedo_rows.append(_row(ns["psnr_albedo"], ns["ssim_albedo"], ns["lpips_albedo"]))
            relit_rows.append(env_rows)
        out["albedo"][case] = _albedo_case(albedo_rows, [1.0, 1.0, 1.0])
        out["relight"][case] = {"views": relit_rows}
    return out


RECORDERS = {"tensoir": record_tensoir, "gs_ir": record_gs_ir, "irgs": record_irgs, "r3dg": record_r3dg}


def record_one(project: str, root: Path) -> None:
    _cpu_cuda()
    _import_torchvision_without_ops()
    with tempfile.TemporaryDirectory() as home:
        _torch_home_with_weights(Path(home))
        torch.set_grad_enabled(False)
        result = RECORDERS[project](root)
    repo, commit, files = PROJECTS[project]
    from importlib.metadata import version
    result["producer"] = {"project": repo, "commit": commit, "files": sorted(files),
                          "lpips": version("lpips"), "torchvision": version("torchvision"),
                          "torch": torch.__version__, "script": "tests/golden/record_presets.py",
                          "fixture": "tests/preset_fixtures.py"}
    golden_path(project).write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
    print(f"wrote {golden_path(project)}")


def main(argv: list[str]) -> None:
    if len(argv) == 3 and argv[0] == "--one":
        record_one(argv[1], Path(argv[2]))
        return
    for arg in argv:
        project, _, root = arg.partition("=")
        if project not in RECORDERS or not root:
            raise SystemExit(f"usage: PROJECT=CHECKOUT ... with PROJECT in {sorted(RECORDERS)}; got {arg!r}")
        subprocess.run([sys.executable, "-m", "tests.golden.record_presets", "--one", project, root], check=True)


if __name__ == "__main__":
    main(sys.argv[1:])

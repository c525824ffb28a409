"""One figure per scene in the paper's style: GT and prediction rows, PSNR under each panel.

Columns: albedo, roughness, metallic, then the relit image under each held-out environment;
rows: ground truth, prediction. Relit images are the evaluator's (``eval.views.relight_view``
with GT normals, the protocol's display transform), so the PSNR printed under a panel is the
masked PSNR of exactly that image, the quantity gspi-eval averages.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from eval.layout import Scene, material_file, read_view_file
from eval.metrics import masked_psnr


def _relit_pair(scene: Scene, view, gt: dict, pred: dict, env_name: str, protocol) -> tuple[np.ndarray, np.ndarray]:
    from eval.imageio import read_exr
    from eval.protocol import display_relit
    from eval.relight import prefilter_environment
    from eval.views import relight_view, view_directions

    env = prefilter_environment(torch.from_numpy(read_exr(scene.envmap_path(env_name))))
    dirs = view_directions(view.K, view.w2c, scene.height, scene.width)
    t = {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in {**gt}.items()}
    p = {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in pred.items()}
    ref = relight_view(t["albedo"], t["roughness"], t["metallic"], t["normal"], dirs, env)
    out = relight_view(p["albedo"], p["roughness"], p["metallic"], t["normal"], dirs, env)
    return display_relit(ref, protocol.relight).numpy(), display_relit(out, protocol.relight).numpy()


def scene_figure(scene: Scene, pred_scene_dir: Path, out_path: Path, protocol, *, split: str = "test",
                 view_index: int = 0) -> Path:
    """Writes the figure of one test view (``view_index``) of ``scene``; returns its path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    view = scene.split_views(split)[view_index]
    gdir, pdir = scene.view_dir(split, view.id), Path(pred_scene_dir) / split / view.id
    mask = read_view_file(gdir, "mask.png")[..., 0] > 0.5
    gt = {c: read_view_file(gdir, material_file(c)) for c in ("albedo", "roughness", "metallic")}
    gt["normal"] = read_view_file(gdir, "normal.exr")
    pred = {c: read_view_file(pdir, material_file(c)) for c in ("albedo", "roughness", "metallic")
            if (pdir / material_file(c)).is_file()}
    h, w = mask.shape
    fills = {"roughness": protocol.relight.fill_roughness, "metallic": protocol.relight.fill_metallic}
    panels = []  # (title, gt image, pred image or None)
    for c in ("albedo", "roughness", "metallic"):
        panels.append((c, gt[c], pred.get(c)))
    if "albedo" in pred:
        full = {c: pred.get(c, np.full((h, w, 1), fills.get(c, 0.0), np.float32)) for c in gt if c != "normal"}
        for env in scene.relight_envs:
            ref, out = _relit_pair(scene, view, gt, full, env, protocol)
            panels.append((f"relit: {env}", ref, out))
    fig, axes = plt.subplots(2, len(panels), figsize=(2.0 * len(panels), 4.4), squeeze=False)
    m = torch.from_numpy(mask)
    for col, (title, g, p) in enumerate(panels):
        for row, img in enumerate((g, p)):
            ax = axes[row, col]
            ax.set_xticks([])
            ax.set_yticks([])
            if img is None:
                ax.text(0.5, 0.5, "--", ha="center", va="center", fontsize=14)
                continue
            shown = np.clip(img, 0, 1) * mask[..., None]
            ax.imshow(shown[..., 0] if shown.shape[-1] == 1 else shown, cmap="gray", vmin=0, vmax=1)
        axes[0, col].set_title(title, fontsize=8)
        if p is not None:
            psnr = masked_psnr(torch.from_numpy(np.ascontiguousarray(p)), torch.from_numpy(np.ascontiguousarray(g)), m)
            axes[1, col].set_xlabel(f"PSNR {psnr:.2f} dB", fontsize=8)
    axes[0, 0].set_ylabel("GT", fontsize=9)
    axes[1, 0].set_ylabel("prediction", fontsize=9)
    fig.suptitle(f"{scene.name}, {split} view {view.id}", fontsize=9)
    fig.tight_layout()
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_path, dpi=110)
    plt.close(fig)
    return out_path

"""One figure per scene in the paper's style: GT and prediction rows, PSNR under each panel.

Columns: albedo, roughness, metallic, then the relit image under each held-out environment;
rows: ground truth, prediction. Every image is the view as the protocol scores it
(``eval.scored_view``: scored mask, aligned albedo, relit images after the scale fit and the
display transform), and the PSNR printed under a panel is the protocol's PSNR of exactly that
image pair (``eval.scoring.psnr_scores``; albedo in the protocol's colour space), the number
gspi-eval averages. ``gspi-run`` writes it for each scene (``gspi.run.runner.write_figures``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from eval.common.layout import MATERIAL_CHANNELS, Scene
from eval.scored_view import EnvironmentCache, ScoredView, scene_scored_views
from eval.scoring import psnr_scores, scored_space


def figure_panels(sv: ScoredView, protocol) -> list[tuple[str, np.ndarray, np.ndarray | None, float | None]]:
    """(title, GT image, predicted image or None, PSNR or None) per column, masked for display."""
    out = []
    for c in MATERIAL_CHANNELS:
        pred = sv.pred.get(c)
        psnr = None
        if pred is not None:
            p, g, _ = scored_space(c, pred, sv.gt[c], protocol)
            psnr = psnr_scores(p, g, sv.mask, protocol.psnr, mask_pred=bool(protocol.mask_prediction))[0]
        out.append((c, sv.gt[c].cpu().numpy(), None if pred is None else pred.cpu().numpy(), psnr))
    for env, pair in sv.relit.items():
        out.append((f"relit: {env}", pair.gt.cpu().numpy(), pair.pred.cpu().numpy(),
                    psnr_scores(pair.pred, pair.gt, sv.mask, protocol.psnr, mask_pred=bool(protocol.mask_prediction))[0]))
    return out


def scene_figure(scene: Scene, pred_scene_dir: Path, out_path: Path, protocol, *, split: str = "test",
                 view_index: int = 0) -> Path:
    """Writes the figure of one scored view of ``scene``: view ``view_index`` of ``split``, or the
    first one after it that is scored (a view that shows nothing of the object, ``gt_channels:
    []``, is not: several of the real objects' held-out views)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sv, cache = None, EnvironmentCache()
    for view in scene.split_views(split)[view_index:]:
        scored, _ = scene_scored_views(scene, Path(pred_scene_dir), protocol, cache, views=[view])
        if scored:
            (sv,) = scored
            break
    if sv is None:
        raise ValueError(f"{scene.root}: no scored {split} view from index {view_index} on: no figure")
    panels = figure_panels(sv, protocol)
    mask = sv.mask.cpu().numpy()
    fig, axes = plt.subplots(2, len(panels), figsize=(2.0 * len(panels), 4.4), squeeze=False)
    for col, (title, g, p, psnr) in enumerate(panels):
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
        if psnr is not None:
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

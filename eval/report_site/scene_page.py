"""One scene's page of the report: comparison grid per view, relighting strip, turntables.

The site's layout (eval.report_site.build writes the rest) `<out>/`:
    index.html                 Tables 1-3, per-scene breakdown, scenes, jobs, problems, figures
    scene_<name>.html          comparison grid per view, relighting strip, turntables, scores
    img/<scene>/...webp        thumbnails (eval.report_site.images)
    anim/<scene>/<job>.webp    gspi-relight turntables copied from <run>/relight/<scene>/
    glb/<scene>/<job>.glb      gspi-export asset= GLBs (and <job>_preview.png) copied from <run>/export/<scene>/
    jobs/<k>/{config.yaml,run.log}   copies, so the links work when the folder is moved
    figures/*.{png,pdf}        the paper's figures (eval.report_site.figures)
"""
from __future__ import annotations

import shutil
from html import escape
from pathlib import Path

import pandas as pd

from eval.records.eval_folder import META_NAME
from eval.report_site.collect import Job
from eval.report_site.html_tables import frame_html
from eval.report_site.images import colorize_error, css_gradient, save_thumbnail
from eval.report_site.page import page, tile, url
from eval.report_site.panels import ERROR_MAX, ViewPanels
from eval.report_site.viewer import viewer_html


def _metric_caption(metrics: dict | None) -> str:
    if not metrics:
        return "&nbsp;"
    psnr = "inf" if metrics["psnr"] == float("inf") else f"{metrics['psnr']:.2f}"
    return (f"PSNR {psnr}<br>SSIM {100 * metrics['ssim']:.1f}% "
            f"LPIPS {100 * metrics['lpips']:.1f}%")


class SceneWriter:
    """Thumbnails and the page of one scene."""

    def __init__(self, out: Path, scene, jobs: list[Job], *, thumb: int, quality: int):
        self.out, self.scene, self.jobs = out, scene, jobs
        self.thumb, self.quality = thumb, quality
        self.keys = {j.label: f"j{k}" for k, j in enumerate(jobs)}

    def _img(self, image, rel: str) -> str:
        save_thumbnail(image, self.out / rel, size=self.thumb, quality=self.quality)
        return rel

    def _pair(self, vp: ViewPanels, label: str, key: str) -> str:
        p = vp.jobs[label][key]
        base = f"img/{self.scene.name}/{vp.view}/{self.keys[label]}_{key.replace(':', '_')}"
        if p.image is None:
            return tile(None, "&nbsp;", note=p.note)
        img = self._img(p.image, base + ".webp")
        err = self._img(colorize_error(p.error, ERROR_MAX), base + "_err.webp")
        return (f"<div class=\"pair\">{tile(img, 'prediction', alt=f'{label} {key}')}"
                f"{tile(err, 'error', alt=f'{label} {key} error')}</div>"
                f"<div class=\"tile\">{_metric_caption(p.metrics)}</div>")

    def _gt(self, vp: ViewPanels, key: str) -> str:
        rel = self._img(vp.gt[key], f"img/{self.scene.name}/{vp.view}/gt_{key.replace(':', '_')}.webp")
        return tile(rel, "ground truth", alt=f"GT {key}")

    def comparison(self, vp: ViewPanels, envs: list[str]) -> str:
        keys = ["albedo", "roughness", "metallic"] + ([f"relit:{envs[0]}"] if envs else [])
        head = "".join(f"<th>{escape(k.replace('relit:', 'relit: '))}</th>" for k in keys)
        rows = [f"<tr><th>GT</th>{''.join(f'<td>{self._gt(vp, k)}</td>' for k in keys)}</tr>"]
        for job in self.jobs:
            cells = "".join(f"<td>{self._pair(vp, job.label, k)}</td>" for k in keys)
            rows.append(f"<tr><th>{escape(job.label)}</th>{cells}</tr>")
        return f"<table class=\"grid\"><tr><th></th>{head}</tr>{''.join(rows)}</table>"

    def strip(self, vp: ViewPanels, envs: list[str], env_imgs: dict[str, str]) -> str:
        top = "".join(f"<th><figure class=\"tile env\"><img src=\"{url(env_imgs[e])}\" "
                      f"alt=\"{escape(e)}\"><figcaption>{escape(e)}</figcaption></figure></th>"
                      for e in envs)
        gts = "".join(f"<td>{self._gt(vp, 'relit:' + e)}</td>" for e in envs)
        rows = [f"<tr><th>GT</th>{gts}</tr>"]
        for job in self.jobs:
            cells = []
            for e in envs:
                p = vp.jobs[job.label][f"relit:{e}"]
                if p.image is None:
                    cells.append(f"<td>{tile(None, '&nbsp;', note=p.note)}</td>")
                    continue
                rel = f"img/{self.scene.name}/{vp.view}/{self.keys[job.label]}_relit_{e}.webp"
                if not (self.out / rel).is_file():  # the comparison grid wrote the first env
                    self._img(p.image, rel)
                cells.append(f"<td>{tile(rel, _metric_caption(p.metrics), alt=f'{job.label} {e}')}</td>")
            rows.append(f"<tr><th>{escape(job.label)}</th>{''.join(cells)}</tr>")
        return f"<table class=\"grid\"><tr><th></th>{top}</tr>{''.join(rows)}</table>"

    def animations(self, all_jobs: list[Job]) -> str:
        parts = []
        for k, job in enumerate(all_jobs):
            src = job.animation(self.scene.name)
            if src is None:
                continue
            rel = f"anim/{self.scene.name}/a{k}.webp"
            (self.out / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(src, self.out / rel)
            parts.append(f"<figure class=\"tile anim\"><img src=\"{url(rel)}\" alt=\"turntable\">"
                         f"<figcaption>{escape(job.label)} (seed {job.seed})</figcaption></figure>")
        if not parts:
            return "<p>No turntable: run <code>gspi-relight asset=&lt;run&gt;/work/&lt;scene&gt;/pbr_gs.ply " \
                   "env=... out=&lt;run&gt;/relight/&lt;scene&gt;</code> to add one.</p>"
        return "".join(parts)

    def glbs(self, all_jobs: list[Job]) -> str:
        """The relightable GLB of each job that exported one: its still (drawn by gspi-export from
        the file, no three.js) linking to a copy of the file."""
        parts, viewable = [], []
        for k, job in enumerate(all_jobs):
            found = job.glb(self.scene.name)
            if found is None:
                continue
            glb, preview = found
            viewable.append((f"a{k}", glb, f"{escape(job.label)} (seed {job.seed})"))
            rel = f"glb/{self.scene.name}/a{k}.glb"
            (self.out / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(glb, self.out / rel)
            caption = (f"<a href=\"{url(rel)}\" download=\"{escape(self.scene.name)}.glb\">{escape(job.label)} "
                       f"(seed {job.seed}): GLB, {glb.stat().st_size / 1e6:.2f} MB</a>")
            image = "<div class=\"missing\">no preview</div>"
            if preview is not None:
                shutil.copyfile(preview, self.out / f"glb/{self.scene.name}/a{k}_preview.png")
                image = (f"<a href=\"{url(rel)}\"><img src=\"{url(f'glb/{self.scene.name}/a{k}_preview.png')}\" "
                         f"alt=\"GLB preview: shaded, base colour, roughness, metallic\"></a>")
            parts.append(f"<figure class=\"tile glb\">{image}<figcaption>{caption}</figcaption></figure>")
        if not parts:
            return "<p>No GLB: run <code>gspi-export asset=&lt;run&gt;/work/&lt;scene&gt;/pbr_gs.ply " \
                   "out=&lt;run&gt;/export/&lt;scene&gt;/pbr_gs.glb</code> to add one.</p>"
        return ("<p>glTF 2.0 (mesh, base colour and metallic-roughness textures; docs/EXPORT.md). "
                "Still: shaded, base colour, roughness, metallic.</p>" + "".join(parts)
                + viewer_html(self.out, self.scene, viewable))

    def asset_checks(self) -> str:
        """The user asset each job started from, checked against the scene's photos (gspi-run's
        ``asset_check``, in the prediction's meta.json): its PSNR, and its warning when below."""
        from eval.common.layout import read_meta

        parts = []
        for job in self.jobs:
            pred = job.prediction(self.scene.name)
            check = ((read_meta(pred).get("asset") or {}).get("asset_check") if pred is not None else None)
            if not check:
                continue
            psnr = check.get("psnr_masked")
            text = (f"{escape(job.label)} (seed {job.seed}): the asset's renders of the {check.get('views')} "
                    f"{escape(str(check.get('split')))} views score "
                    f"{'n/a' if psnr is None else f'{psnr:.2f}'} dB masked display PSNR against the photos "
                    f"(threshold {check.get('min_psnr')} dB)")
            if check.get("passed", True):
                parts.append(f"<li>{text}.</li>")
            else:
                parts.append(f"<li class=\"warning\"><strong>Warning:</strong> {text}: the asset may not "
                             f"depict this scene.</li>")
        if not parts:
            return ""
        return "<h2>User asset check</h2><ul class=\"asset-check\">" + "".join(parts) + "</ul>"

    def scene_scores(self) -> str:
        """Per-scene means of every shown job (eval_meta.json per_scene)."""
        import json

        rows = {}
        for job in self.jobs:
            meta = None if job.eval_dir is None else job.eval_dir / META_NAME
            if meta is None or not meta.is_file():
                continue
            per_scene = (json.loads(meta.read_text()).get("per_scene") or {}).get(self.scene.name, {})
            rows[job.label] = {f"{m} {c}": per_scene.get(c, {}).get(m, float("nan"))
                               * (100 if m != "psnr" else 1)
                               for m in ("psnr", "ssim", "lpips")
                               for c in ("albedo", "roughness", "metallic", "relight")}
        if not rows:
            return "<p>No scores.</p>"
        return frame_html(pd.DataFrame(rows).T, index_name="method (SSIM, LPIPS in %)")

    def protocol_text(self) -> str:
        """"protocol <name> v<k>, LPIPS <net> v<version>" of the first job that states it."""
        p = next((j.protocol for j in self.jobs if j.protocol), {})
        lpips = p.get("lpips") or {}
        return (f"protocol {p.get('name', '?')} v{p.get('version', '?')}, LPIPS "
                f"{lpips.get('net', '?')} v{lpips.get('version', '?')}, relit: "
                f"{(p.get('relight') or {}).get('tonemap', '?')} tone map, GT normals")

    def write(self, panels: list[ViewPanels], envs: list[str], env_images: dict, all_jobs) -> Path:
        env_imgs = {e: self._img(img, f"img/{self.scene.name}/env_{e}.webp")
                    for e, img in env_images.items()}
        buttons = "".join(f"<button data-view=\"{escape(vp.view)}\">{escape(vp.view)}</button>"
                          for vp in panels)
        views = "".join(
            f"<div class=\"view\" data-view=\"{escape(vp.view)}\"><h2>Comparison, view "
            f"{escape(vp.view)}</h2>{self.comparison(vp, envs)}<h2>Relighting, view "
            f"{escape(vp.view)}</h2>{self.strip(vp, envs, env_imgs)}</div>" for vp in panels)
        body = (f"<p><a href=\"index.html\">&larr; report</a></p><h1>{escape(self.scene.name)}</h1>"
                f"{self.asset_checks()}<p class=\"views\">View: {buttons}</p>"
                f"<p>Error maps: |prediction − GT| (mean over colour channels, display values) "
                f"<span class=\"cbar\" style=\"background:{css_gradient()}\"></span> 0 to "
                f"{ERROR_MAX} (clipped), colour map magma. Scores under each panel: per_view.csv "
                f"of the job's gspi-eval ({escape(self.protocol_text())}).</p>{views}"
                f"<h2>Relit asset (gspi-relight)</h2>{self.animations(all_jobs)}"
                f"<h2>Relightable asset (gspi-export)</h2>{self.glbs(all_jobs)}"
                f"<h2>Scores, this scene (mean over test views)</h2>{self.scene_scores()}")
        path = self.out / f"scene_{self.scene.name}.html"
        path.write_text(page(f"{self.scene.name} - gspi report", body))
        return path

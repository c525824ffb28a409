"""An interactive viewer of a scene's relightable GLBs on its report page (issue 41).

Each exported GLB is shown in Google's `<model-viewer>` (vendored: `eval.report_site.model_viewer`)
with the run's environments to choose from as image-based lighting: the scene's capture and
relighting HDRIs (`<data>/<scene>/envmaps/<env>.exr`), each written as a Radiance .hdr of
`ENV_ROWS` rows. A report opened from the file system cannot fetch files (browsers refuse
file:// requests from file:// pages), so the GLBs and HDRIs travel as data URLs inside small
classic scripts (`viewer/<scene>/<key>.js`, `window.GSPI_VIEWER[key] = "data:..."`) that the
page loads with `<script src>`; model-viewer picks its HDR loader by a URL ending in `.hdr`,
which the data URL's fragment `#<env>.hdr` provides (fetch drops the fragment).
"""
from __future__ import annotations

import base64
import json
import shutil
from html import escape
from pathlib import Path

import numpy as np
import torch

from eval.common.imageio import read_exr
from eval.radiance_hdr import encode_hdr
from eval.report_site.model_viewer import SCRIPT, installed_script
from eval.report_site.page import url

ENV_ROWS = 128   # lat-long rows of the viewer's HDRIs (256 x 128: ~130 kB each)
SCRIPT_DIR = "js"


def install_script(out: Path) -> str | None:
    """Copies the vendored bundle and its LICENSE into ``<out>/js/`` once; its page-relative path."""
    src = installed_script()
    if src is None:
        return None
    dst = out / SCRIPT_DIR / SCRIPT
    if not dst.is_file():
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, dst)
        shutil.copyfile(src.parent / "LICENSE", dst.parent / "model-viewer.LICENSE")
    return f"{SCRIPT_DIR}/{SCRIPT}"


def data_script(path: Path, key: str, payload: bytes, mime: str, suffix: str = "") -> None:
    """``window.GSPI_VIEWER[key] = "data:<mime>;base64,...<suffix>"`` as a classic script."""
    data = f"data:{mime};base64,{base64.b64encode(payload).decode()}{suffix}"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"(window.GSPI_VIEWER = window.GSPI_VIEWER || {{}})[{json.dumps(key)}] = {json.dumps(data)};\n")


def env_hdr(exr: Path, rows: int = ENV_ROWS) -> bytes:
    """A lat-long EXR resampled to ``rows`` x 2 ``rows`` texels (area-averaged down, bilinear up:
    model-viewer's prefiltering turns maps of a few texels black), as .hdr bytes."""
    env = torch.from_numpy(np.ascontiguousarray(read_exr(exr)[..., :3], dtype=np.float32)).permute(2, 0, 1)[None]
    if env.shape[-2] != rows:
        mode = dict(mode="area") if env.shape[-2] > rows else dict(mode="bilinear", align_corners=False)
        env = torch.nn.functional.interpolate(env, size=(rows, 2 * rows), **mode)
    return encode_hdr(env[0].permute(1, 2, 0).numpy())


def scene_envs(scene) -> list[str]:
    """The scene's environments with a map: capture first, then the relighting ones."""
    names = [scene.capture_env, *scene.relight_envs]
    return [n for n in dict.fromkeys(names) if scene.envmap_path(n).is_file()]


def viewer_html(out: Path, scene, glbs: list[tuple[str, Path, str]]) -> str:
    """The viewers of ``glbs`` ((key, GLB file, caption) per job) with the scene's HDRIs; "" when
    the viewer is not installed or there is nothing to show."""
    script = install_script(out)
    if script is None or not glbs:
        return ("<p>No interactive viewer: its script is not installed "
                "(<code>python -m eval.report_site.model_viewer</code>, run by <code>make install</code>).</p>"
                if glbs else "")
    folder = f"viewer/{scene.name}"
    envs = scene_envs(scene)
    scripts = [script]
    for env in envs:
        rel = f"{folder}/env_{len(scripts)}.js"
        data_script(out / rel, f"env:{scene.name}:{env}", env_hdr(scene.envmap_path(env)),
                    "application/octet-stream", suffix=f"#{env}.hdr")
        scripts.append(rel)
    figures = []
    options = "".join(f"<option value=\"{escape(e)}\">{escape(e)}</option>" for e in envs)
    for key, glb, caption in glbs:
        rel = f"{folder}/{key}.js"
        data_script(out / rel, f"glb:{scene.name}:{key}", Path(glb).read_bytes(), "model/gltf-binary")
        scripts.append(rel)
        figures.append(
            f"<figure class=\"tile viewer\"><model-viewer data-scene=\"{escape(scene.name)}\" data-key=\"{escape(key)}\" "
            f"camera-controls tone-mapping=\"neutral\" shadow-intensity=\"0\" interaction-prompt=\"none\" "
            f"style=\"width:360px;height:360px;background:#202020\"></model-viewer>"
            f"<figcaption>{caption}<br>lighting: <select class=\"viewer-env\">{options}</select></figcaption></figure>")
    tags = "".join(f"<script src=\"{url(s)}\"></script>" for s in scripts)
    return (tags + "<p>Drag to turn, scroll to zoom; the lighting is the scene's environments "
            "(image-based, <code>&lt;model-viewer&gt;</code> " + escape(SCRIPT) + ").</p>"
            + "".join(figures) + f"<script>{INIT_JS}</script>")


# Each viewer gets its GLB and the first environment; the select switches the environment.
INIT_JS = """
document.querySelectorAll('model-viewer[data-key]').forEach(function (mv) {
  var data = window.GSPI_VIEWER || {}, scene = mv.dataset.scene;
  var select = mv.parentNode.querySelector('select.viewer-env');
  function light() { if (select && select.value) mv.environmentImage = data['env:' + scene + ':' + select.value]; }
  light();
  if (select) select.addEventListener('change', light);
  mv.src = data['glb:' + scene + ':' + mv.dataset.key];
});
"""

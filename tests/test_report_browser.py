"""The report in a real browser: headless Chromium over the DevTools pipe (tests/cdp.py).

Skipped when no Chromium is installed (`make chromium` installs Debian's package). The
browser part takes ~6 s on the 2-core VM, on top of building the tiny report (~20 s, shared
with test_report_site.py: tests/report_fixtures.shared_report). `GSPI_REPORT=<dir>` also
checks an existing report, e.g. `GSPI_REPORT=demo_out/report` after `make demo` (~25 s for the
demo's 5 pages). Screenshots go to the test's tmp folder and, when GSPI_SCREENSHOTS is set, to
that folder too (to look at them).
"""
import os
import re
import shutil
from pathlib import Path

import pytest

from tests.cdp import Browser, find_chromium
from tests.report_fixtures import shared_report

CHROMIUM = find_chromium()
# CI (.ci/run) installs Chromium and sets this: there the browser test must run, never skip.
REQUIRED = os.environ.get("GSPI_REQUIRE_CHROMIUM") == "1"
pytestmark = pytest.mark.skipif(CHROMIUM is None and not REQUIRED, reason="no chromium on PATH (install "
                                "it with `make chromium`: Debian's chromium package)")


@pytest.fixture
def chromium() -> str:
    if CHROMIUM is None:
        pytest.fail("GSPI_REQUIRE_CHROMIUM=1 but no chromium on PATH: `make chromium` (Debian's package, "
                    "run by .ci/run) did not install it")
    return CHROMIUM

ROWS = "Array.from(document.querySelectorAll('#table1 tbody tr')).map(r => r.cells[0].textContent)"
BROKEN = ("Array.from(document.images).filter(i => !(i.complete && i.naturalWidth > 0))"
          ".map(i => i.getAttribute('src'))")
SHOWN = "Array.from(document.querySelectorAll('.view.on')).map(v => v.dataset.view)"


@pytest.fixture(scope="module")
def report(tmp_path_factory, lpips_net):
    return shared_report(tmp_path_factory, lpips_net)[1]


def _keep(path: Path) -> Path:
    target = os.environ.get("GSPI_SCREENSHOTS")
    if target:
        Path(target).mkdir(parents=True, exist_ok=True)
        shutil.copy(path, Path(target) / path.name)
    return path


def table1_methods(index: Path) -> list[str]:
    """Row labels of Table 1's jobs, from the jobs table of the page source."""
    jobs = re.search(r'id="jobs">.*?<tbody>(.*?)</tbody>', index.read_text(), re.S).group(1)
    return sorted({m.group(1) for m in re.finditer(r'<tr><td data-v="([^"]*)">[^<]*</td>'
                                                  r'<td data-v="table1">', jobs)})


def check_site(browser: Browser, out: Path, shots: Path, prefix: str) -> None:
    """Every page: no console error, every image loaded; Table 1: one row per method and
    sorting reverses it; a scene page's view selector switches views. Saves screenshots."""
    index = out / "index.html"
    browser.open(index)
    assert browser.errors() == []
    assert browser.evaluate(BROKEN) == []
    before = browser.evaluate(ROWS)
    assert sorted(before) == table1_methods(index)
    browser.evaluate("document.querySelectorAll('#table1 th')[1].click()")
    ascending = browser.evaluate(ROWS)
    browser.evaluate("document.querySelectorAll('#table1 th')[1].click()")
    descending = browser.evaluate(ROWS)
    assert sorted(ascending) == sorted(before)
    if len(set(before)) > 1:
        assert ascending == descending[::-1] and ascending != descending
    _keep(browser.screenshot(shots / f"{prefix}_index.png"))
    scenes = sorted(out.glob("scene_*.html"))
    assert scenes
    for page in scenes:
        browser.open(page)
        assert browser.errors() == [], page.name
        assert browser.evaluate(BROKEN) == [], page.name
        assert browser.evaluate("document.images.length") > 0, page.name
    browser.open(scenes[0])
    views = browser.evaluate("Array.from(document.querySelectorAll('.views button'))"
                             ".map(b => b.dataset.view)")
    assert browser.evaluate(SHOWN) == views[:1]
    browser.evaluate(f"document.querySelectorAll('.views button')[{len(views) - 1}].click()")
    assert browser.evaluate(SHOWN) == views[-1:]
    _keep(browser.screenshot(shots / f"{prefix}_scene.png"))


def test_report_in_headless_chromium(report, chromium, tmp_path):
    with Browser(chromium) as browser:
        check_site(browser, report.out, tmp_path, "report")
        browser.open(report.index)
        assert sorted(browser.evaluate(ROWS)) == ["GS-PI (ours)", "Joint IR (GS-IR-style)",
                                                  "No decomposition"]
        browser.open(report.scene_pages["sphere_1"])   # joint_ir has no sphere_1: tiles say so
        assert browser.evaluate("document.querySelectorAll('.missing').length") >= 12
    assert (tmp_path / "report_scene.png").stat().st_size > 10_000


@pytest.mark.skipif(not os.environ.get("GSPI_REPORT"), reason="set GSPI_REPORT=<report dir> "
                    "(e.g. demo_out/report after make demo) to check an existing report")
def test_existing_report_in_headless_chromium(chromium, tmp_path):
    out = Path(os.environ["GSPI_REPORT"])
    assert (out / "index.html").is_file(), f"{out}: no index.html"
    with Browser(chromium) as browser:
        check_site(browser, out, tmp_path, "existing")
    with_viewer = [p for p in sorted(out.glob("scene_*.html")) if "<model-viewer" in p.read_text()]
    with Browser(chromium, webgl=True, width=900, height=900) as browser:
        for page in with_viewer:  # every exported GLB, under 3 of the run's HDRIs
            assert check_viewer(browser, page, tmp_path) == 3, page.name


# The viewer's canvas as a PNG data URL once its model is loaded and shown (model-viewer's own API).
VIEWER_PIXELS = """(async () => {
  const mv = document.querySelector('model-viewer[data-key]');
  mv.scrollIntoView();  // model-viewer renders only while it is on screen
  const t0 = Date.now();
  while (!(mv.loaded && mv.modelIsVisible) && Date.now() - t0 < 60000) await new Promise(r => setTimeout(r, 200));
  await new Promise(r => setTimeout(r, 1500));
  return {loaded: mv.loaded, png: mv.toDataURL('image/png')};
})()"""


def _pixels(data_url: str):
    import base64
    import io

    import numpy as np
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(base64.b64decode(data_url.split(",", 1)[1]))).convert("RGBA"),
                      dtype=np.float64) / 255.0


def check_viewer(browser: Browser, page: Path, shots: Path, max_envs: int = 3) -> int:
    """The page's first <model-viewer> loads its GLB (the object covers pixels, not all) and
    each of up to ``max_envs`` of the run's environments lights it differently from the one
    before. Returns the number of environments checked."""
    import numpy as np
    from PIL import Image

    browser.open(page)
    envs = browser.evaluate("Array.from(document.querySelector('select.viewer-env').options).map(o => o.value)")
    assert len(envs) >= 2, (page.name, envs)
    shown = []
    for k, env in enumerate(envs[:max_envs]):
        browser.evaluate(f"(() => {{ const s = document.querySelector('select.viewer-env'); s.value = {env!r}; "
                         "s.dispatchEvent(new Event('change')); })()")
        state = browser.evaluate(VIEWER_PIXELS, timeout=90)
        assert state["loaded"], (page.name, browser.errors())
        shown.append(_pixels(state["png"]))
        Image.fromarray((shown[-1] * 255).astype("uint8")).save(shots / f"viewer_{page.stem}_{k}.png")
        _keep(shots / f"viewer_{page.stem}_{k}.png")
    assert [e for e in browser.errors() if "model-viewer" in e.lower() or "glb" in e.lower()] == []
    for before, after in zip(shown, shown[1:]):
        covered = (before[..., 3] > 0.5) & (after[..., 3] > 0.5)
        assert 0.02 < covered.mean() < 0.9, (page.name, covered.mean())  # the object, not the whole canvas
        assert np.abs(before[..., :3] - after[..., :3])[covered].mean() > 0.01, page.name  # relit
    return len(shown)


def test_viewer_turns_the_glb_and_relights_it(report, chromium, tmp_path):
    """The scene page's <model-viewer> (vendored; the page opened from file:// without extra
    flags) loads the exported GLB: the object covers pixels, and another of the run's
    environments changes them."""
    from eval.report_site.model_viewer import installed_script

    if installed_script() is None:
        pytest.fail("the viewer's script is not installed: python -m eval.report_site.model_viewer "
                    "(make install runs it)")
    page = report.scene_pages["sphere_0"]
    assert "<model-viewer" in page.read_text()
    assert (report.out / "js" / "model-viewer.LICENSE").is_file()
    with Browser(chromium, webgl=True, width=900, height=900) as browser:
        assert check_viewer(browser, page, tmp_path) == 3

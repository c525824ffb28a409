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
        assert sorted(browser.evaluate(ROWS)) == ["Joint IR (GS-IR-style)", "No decomposition",
                                                  "Ours"]
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

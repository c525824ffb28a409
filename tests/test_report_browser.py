"""The report in a real browser: headless Chromium over the DevTools pipe (tests/cdp.py).

Skipped when no Chromium is installed (`make chromium` installs Debian's package). The
browser part takes ~7 s on the 2-core VM, on top of building the tiny report (~20 s, shared
with test_report_site.py: tests/report_fixtures.shared_report). Screenshots go to the test's tmp folder and, when
GSPI_SCREENSHOTS is set, to that folder too (to look at them).
"""
import os
import shutil
from pathlib import Path

import pytest

from tests.cdp import Browser, find_chromium
from tests.report_fixtures import shared_report

CHROMIUM = find_chromium()
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (install it with "
                                "`make chromium`: Debian's chromium package)")

ROWS = "Array.from(document.querySelectorAll('#table1 tbody tr')).map(r => r.cells[0].textContent)"
BROKEN = ("Array.from(document.images).filter(i => !(i.complete && i.naturalWidth > 0))"
          ".map(i => i.getAttribute('src'))")


@pytest.fixture(scope="module")
def report(tmp_path_factory, lpips_net):
    return shared_report(tmp_path_factory, lpips_net)[1]


def _keep(path: Path) -> None:
    target = os.environ.get("GSPI_SCREENSHOTS")
    if target:
        Path(target).mkdir(parents=True, exist_ok=True)
        shutil.copy(path, Path(target) / path.name)


def test_report_in_headless_chromium(report, tmp_path):
    with Browser(CHROMIUM) as browser:
        browser.open(report.index)
        assert browser.errors() == []
        assert browser.evaluate(BROKEN) == []
        assert browser.evaluate("document.images.length") >= 2      # the figures
        before = browser.evaluate(ROWS)
        assert sorted(before) == sorted(["Joint IR (GS-IR-style)", "No decomposition", "Ours"])
        # sort by albedo PSNR: two clicks give opposite orders, both differ from one another
        browser.evaluate("document.querySelectorAll('#table1 th')[1].click()")
        ascending = browser.evaluate(ROWS)
        browser.evaluate("document.querySelectorAll('#table1 th')[1].click()")
        descending = browser.evaluate(ROWS)
        assert ascending == descending[::-1] and ascending != descending
        assert sorted(ascending) == sorted(before)
        _keep(browser.screenshot(tmp_path / "report_index.png"))

        for name, page in report.scene_pages.items():
            browser.open(page)
            assert browser.errors() == [], name
            assert browser.evaluate(BROKEN) == [], name
            assert browser.evaluate("document.querySelectorAll('.missing').length") > 0, name
        browser.open(report.scene_pages["sphere_0"])
        shown = "Array.from(document.querySelectorAll('.view.on')).map(v => v.dataset.view)"
        assert browser.evaluate(shown) == ["000"]
        browser.evaluate("document.querySelector('.views button[data-view=\"001\"]').click()")
        assert browser.evaluate(shown) == ["001"]
        _keep(browser.screenshot(tmp_path / "report_scene.png"))
    assert (tmp_path / "report_scene.png").stat().st_size > 10_000

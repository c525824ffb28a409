"""gspi-report: the static site from a tiny real sweep, and bad input shown, never a crash."""
import re
from html import unescape
from pathlib import Path

import pytest
from omegaconf import OmegaConf
from PIL import Image

from eval.report_site.build import build_report
from eval.report_site.collect import collect_jobs, resolve_data
from tests.report_fixtures import shared_report

CONF = Path(__file__).resolve().parents[1] / "conf" / "gspi_report.yaml"


@pytest.fixture(scope="module")
def sweep(tmp_path_factory, lpips_net) -> Path:
    return shared_report(tmp_path_factory, lpips_net)[0]


@pytest.fixture(scope="module")
def site(tmp_path_factory, lpips_net):
    return shared_report(tmp_path_factory, lpips_net)[1]


def test_collect_lists_complete_failed_killed(sweep):
    jobs, problems = collect_jobs([sweep])
    assert [j.label for j in jobs] == ["Joint IR (GS-IR-style)", "No decomposition",
                                       "A6: w/o distill", "GS-PI (ours)", "GS-PI (ours, Full)"]  # paper order
    assert all(j.data == (sweep.parent / "data").resolve() for j in jobs)  # "data" found upward
    kinds = sorted(p.kind for p in problems)
    assert kinds == ["failed", "killed", "scene failed"]
    assert any("boom" in p.message for p in problems)


def test_resolve_data_override_wins(tmp_path):
    (tmp_path / "other").mkdir()
    assert resolve_data("nope", tmp_path, str(tmp_path / "other")) == (tmp_path / "other").resolve()
    assert resolve_data("nope", tmp_path, None) is None


def test_index_has_one_row_per_method_and_the_problems(site):
    html = site.index.read_text()
    body = re.search(r'<table class="metrics" id="table1">.*?<tbody>(.*?)</tbody>', html, re.S).group(1)
    rows = re.findall(r"<tr>.*?</tr>", body, re.S)
    assert len(rows) == 3
    assert html.count('class="best"') >= 1 and html.count('class="second"') >= 1
    assert "Protocol: gspi-decoupled v1" in html           # the footer
    assert '<table class="metrics" id="table3">' in html    # Table 3 from its two rows
    assert "ValueError: boom" in html                      # the failed job
    assert "without result.json" in html                   # the killed job
    assert "Joint IR (GS-IR-style), sphere_1: RuntimeError: out of memory" in html
    for link in re.findall(r'href="(jobs/[^"]+)"', html):  # configs and logs copied
        assert (site.out / link).is_file()
    assert 'href="jobs/0/config.yaml"' in html and 'href="jobs/0/run.log"' in html


def test_every_image_reference_exists_and_missing_tiles_are_tiles(site):
    for page in [site.index, *site.scene_pages.values()]:
        html = page.read_text()
        for src in re.findall(r'<img src="([^"]+)"', html):
            assert (site.out / src).is_file(), f"{page.name}: {src}"
            assert not src.startswith(("http:", "https:", "//"))
    s1 = site.scene_pages["sphere_1"].read_text()
    assert "missing: RuntimeError: out of memory" in s1    # joint_ir has no sphere_1
    s0 = site.scene_pages["sphere_0"].read_text()
    assert s0.count(">not modelled<") == 2 * 3            # no_decomposition: rough+metal x 3 views
    assert "anim/sphere_0/" in s0                         # the turntable is embedded
    glb = re.findall(r'<a href="(glb/sphere_0/[^"]+\.glb)"', s0)   # the GLB linked, its copy there
    assert glb and all((site.out / g).read_bytes().startswith(b"glTF") for g in glb)
    assert 'src="glb/sphere_0/' in s0 and "No GLB" in site.scene_pages["sphere_1"].read_text()
    assert "protocol gspi-decoupled v1, LPIPS alex v0.1" in s0
    assert "http" not in s0.replace("http-equiv", "")     # no network anywhere


def test_thumbnails_and_error_maps(site):
    thumbs = list((site.out / "img").rglob("*.webp"))
    assert thumbs and all(Image.open(p).size[0] <= 128 for p in thumbs)
    errs = [p for p in thumbs if p.stem.endswith("_err")]
    assert errs
    # gspi's roughness is off by exactly 0.1 inside the mask: its error map is not black
    err = Image.open(next(p for p in errs if "j2_roughness" in p.name and "sphere_0/000" in str(p)))
    assert max(err.convert("L").getextrema()) > 20


def test_figures_png_and_pdf(site):
    names = sorted(p.name for p in site.figures)
    assert names == ["ablation_stage3.pdf", "ablation_stage3.png", "qualitative.pdf",
                     "qualitative.png", "teaser_scatter.pdf", "teaser_scatter.png"]
    assert all(p.stat().st_size > 1000 for p in site.figures)


def test_size_budget_extrapolates_under_50_mb(site):
    """20 scenes x 5 methods at the same thumbnail size: under 50 MB (per scene-method bytes
    measured here, scenes have 3 views; the paper's have 8, so scale by 8/3)."""
    scene_bytes = sum(p.stat().st_size for p in (site.out / "img").rglob("*") if p.is_file())
    per_scene_method = scene_bytes / (2 * 3)    # GT counted with the methods: an overestimate
    assert per_scene_method * 20 * 5 * 8 / 3 < 50e6


def test_cli_run_and_errors(sweep, tmp_path, capsys):
    from eval.report_site.cli import run

    cfg = OmegaConf.load(CONF)
    cfg.runs, cfg.out, cfg.figures, cfg.max_views = [str(sweep)], str(tmp_path / "r"), False, 1
    cfg.bootstrap.n = 100
    site = run(cfg)
    printed = capsys.readouterr()
    assert "open file://" in printed.out
    progress = [line for line in printed.err.splitlines() if line.startswith("gspi-report: ")]
    scenes = sorted(site.scene_pages)
    assert [f"gspi-report: scene {k}/{len(scenes)}: {s}" for k, s in enumerate(scenes, 1)] == \
        [line for line in progress if line.startswith("gspi-report: scene ")], progress
    assert progress[-1] == f"gspi-report: index: {site.index}"
    assert len(re.findall(r'<button data-view=', site.scene_pages["sphere_0"].read_text())) == 1
    cfg.runs = [str(tmp_path / "nowhere")]
    with pytest.raises(FileNotFoundError, match="nowhere"):
        run(cfg)


def test_empty_folder_gives_a_page_not_a_crash(tmp_path):
    (tmp_path / "runs").mkdir()
    site = build_report([tmp_path / "runs"], tmp_path / "r")
    assert "No table" in site.index.read_text()


def test_malformed_record_is_listed(sweep, tmp_path):
    bad = tmp_path / "runs" / "broken"
    bad.mkdir(parents=True)
    (bad / "result.json").write_text("{not json")
    site = build_report([tmp_path / "runs"], tmp_path / "r")
    assert "malformed" in site.index.read_text() and "invalid JSON" in site.index.read_text()


def test_missing_prediction_is_listed_and_tiled(sweep, tmp_path):
    import shutil

    job = tmp_path / "runs" / "method=no_decomposition"
    shutil.copytree(sweep / "method=no_decomposition", job)
    shutil.rmtree(job / "predictions" / "sphere_1")   # gone, and no scene_errors says why
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "keep.txt").write_text("not the report's")
    site = build_report([tmp_path / "runs"], tmp_path / "r", data=str(sweep.parent / "data"),
                        figures=False)
    assert "No decomposition has no prediction for sphere_1" in site.index.read_text()
    assert "missing: no prediction for this scene" in site.scene_pages["sphere_1"].read_text()
    assert (tmp_path / "r" / "keep.txt").is_file()     # only the report's own files are replaced


def test_unreadable_prediction_is_a_tile_not_a_crash(sweep, tmp_path):
    import shutil

    import numpy as np

    from eval.common.layout import write_material

    job = tmp_path / "runs" / "method=gspi"
    shutil.copytree(sweep / "method=gspi", job)
    write_material(job / "predictions" / "sphere_0" / "test" / "001", "roughness",
                   np.zeros((8, 8), np.float32))                  # wrong size
    (job / "predictions" / "sphere_1" / "test" / "000" / "albedo.png").write_bytes(b"not a png")
    site = build_report([tmp_path / "runs"], tmp_path / "r", data=str(sweep.parent / "data"),
                        figures=False)
    s0 = site.scene_pages["sphere_0"].read_text()
    assert "unreadable:" in s0 and "size 8x8" in s0   # the message gspi-eval gives for the same file
    assert "unreadable:" in site.scene_pages["sphere_1"].read_text()


def test_dataset_not_found_is_listed(sweep, tmp_path):
    import json
    import shutil

    job = tmp_path / "runs" / "method=gspi"
    shutil.copytree(sweep / "method=gspi", job)
    record = json.loads((job / "result.json").read_text())
    (job / "result.json").write_text(json.dumps(dict(record, data="no/such/data")))
    site = build_report([tmp_path / "runs"], tmp_path / "r", figures=False)
    html = unescape(site.index.read_text())
    assert "dataset 'no/such/data' not found (give gt=<dataset dir>)" in html
    assert "sphere_0: no ground truth found" in html and site.scene_pages == {}


def test_hydra_overrides_compose():
    """`gt=` (not `data=`: conf/data/ is a config group) and positional folders."""
    from hydra import compose, initialize_config_dir

    from eval.common.conf import CONF_DIR
    from eval.tables.cli import positional_to_overrides

    overrides = positional_to_overrides(["/tmp", "out=/tmp/r", "gt=/tmp/data", "max_views=2"])
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose("gspi_report", overrides=overrides)
    assert list(cfg.runs) == ["/tmp"] and cfg.gt == "/tmp/data" and cfg.max_views == 2


def test_viewer_install_checks_the_tarball_and_the_bundle(tmp_path, monkeypatch):
    """eval.report_site.model_viewer refuses a tarball whose SHA-256 is not the pinned one, and
    says so in one line when npm is missing; nothing is left looking installed."""
    import io
    import tarfile

    import eval.common.npm_package
    from eval.common.npm_package import NpmUnavailable
    from eval.report_site import model_viewer

    monkeypatch.setenv("GSPI_CACHE", str(tmp_path / "cache"))
    fake = tmp_path / model_viewer.TARBALL
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        for member in model_viewer.FILES.values():
            info = tarfile.TarInfo(member)
            info.size = 4
            tar.addfile(info, io.BytesIO(b"fake"))
    fake.write_bytes(buf.getvalue())
    with pytest.raises(NpmUnavailable, match="SHA-256"):
        model_viewer.install(fake)
    assert model_viewer.installed_script() is None
    monkeypatch.setattr(eval.common.npm_package.shutil, "which", lambda _: None)
    with pytest.raises(NpmUnavailable, match="npm not found.*3D viewer"):
        model_viewer.install()


def test_viewer_hdr_is_the_environment_resampled(tmp_path):
    """The viewer's HDRI: the scene's EXR at 128 x 256, RGBE-encoded (read back within RGBE
    rounding); a constant map stays constant whichever way it is resampled."""
    import numpy as np

    from eval.common.imageio import write_exr
    from eval.radiance_hdr import read_hdr
    from eval.report_site.viewer import ENV_ROWS, env_hdr

    for rows in (16, 512):
        write_exr(tmp_path / "e.exr", np.full((rows, 2 * rows, 3), [0.5, 1.0, 2.0], np.float32))
        (tmp_path / "e.hdr").write_bytes(env_hdr(tmp_path / "e.exr"))
        back = read_hdr(tmp_path / "e.hdr")
        assert back.shape == (ENV_ROWS, 2 * ENV_ROWS, 3)
        np.testing.assert_allclose(back, np.broadcast_to([0.5, 1.0, 2.0], back.shape), rtol=2 ** -7)


def single_scene_run(sweep: Path, tmp_path: Path) -> tuple[Path, Path]:
    """A `gspi-run data=<scene folder>` job (its record's data is the scene's own folder, its one
    scene named after it) with gspi-relight and gspi-export outputs where README writes them."""
    import json
    import shutil

    scene = shutil.copytree(sweep.parent / "data" / "sphere_0", tmp_path / "my" / "sphere_0")
    job = shutil.copytree(sweep / "method=gspi", tmp_path / "runs" / "mine")
    record = json.loads((job / "result.json").read_text())
    (job / "result.json").write_text(json.dumps(dict(record, data=str(scene), scenes=["sphere_0"])))
    return job, scene


@pytest.mark.parametrize("gt", ["recorded", "scene", "parent"])
def test_a_single_scene_run_gets_its_scene_page(sweep, tmp_path, gt):
    """Issue 54: gt= the scene's own folder, its parent, or nothing (the recorded scene folder)."""
    job, scene = single_scene_run(sweep, tmp_path)
    data = {"recorded": None, "scene": str(scene), "parent": str(scene.parent)}[gt]
    site = build_report([job], tmp_path / "r", data=data, figures=False)
    assert list(site.scene_pages) == ["sphere_0"]
    html = site.scene_pages["sphere_0"].read_text()
    assert "anim/sphere_0/" in html and "glb/sphere_0/" in html  # relight/<scene>/, export/<scene>/ shown


def test_a_report_with_no_ground_truth_at_all_exits_2_naming_the_scene(sweep, tmp_path):
    from eval.report_site.cli import main
    from tests.reliability.helpers import run_cli

    job, _ = single_scene_run(sweep, tmp_path)
    code, text = run_cli(main, [str(job), f"out={tmp_path / 'r'}", f"gt={tmp_path / 'runs'}", "figures=false"])
    assert code == 2 and "Traceback" not in text, text[-2000:]
    assert "sphere_0" in text.splitlines()[-1] and "gt=" in text.splitlines()[-1], text[-2000:]

"""benchmarks/bench_controlled_pairs.py: masked means, per-pair verdicts and fractions, on hand-made predictions."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from benchmarks.bench_controlled_pairs import main, masked_means, score_pairs, score_run
from gspi.publish.pairs import pairs_table
from eval.common.imageio import write_png
from gspi.data.controlled_pairs import write_manifest

REPO = Path(__file__).resolve().parents[1]
ROUGH = {"id": "c00", "kind": "roughness", "family": "sphere", "albedo_linear": [0.5] * 3,
         "scenes": {"glossy": "g", "matte": "m"}, "values": {"glossy": 0.1, "matte": 0.8}}
METAL = {"id": "c01", "kind": "metal", "family": "torus", "albedo_linear": [1.0, 0.78, 0.34],
         "scenes": {"dielectric": "d", "metal": "x"}, "values": {"dielectric": 0.0, "metal": 1.0}}


def means(**scenes: tuple[float, float]) -> dict[str, dict[str, float]]:
    return {name: {"roughness": r, "metallic": m} for name, (r, m) in scenes.items()}


class TestScorePairs:
    def test_a_reading_that_orders_and_separates_scores_one(self):
        s = score_pairs([ROUGH, METAL], means(g=(0.1, 0.0), m=(0.7, 0.0), d=(0.2, 0.1), x=(0.2, 0.9)))
        assert s["roughness"] == {"pairs": 1, "ordered": 1.0, "ordered_with_gap": 1.0}
        assert s["metal"] == {"pairs": 1, "separated": 1.0}
        assert s["pairs"][0]["gap"] == pytest.approx(0.6)

    def test_ordered_with_a_small_gap_counts_as_ordered_only(self):
        s = score_pairs([ROUGH], means(g=(0.30, 0.0), m=(0.50, 0.0)))
        assert s["roughness"]["ordered"] == 1.0 and s["roughness"]["ordered_with_gap"] == 0.0

    def test_inverted_pair_as_issue_52_saw_it(self):  # glossy predicted 0.21, matte 0.16
        s = score_pairs([ROUGH], means(g=(0.21, 0.0), m=(0.16, 0.0)))
        assert s["roughness"]["ordered"] == 0.0 and not s["pairs"][0]["ordered"]
        assert s["pairs"][0]["gap"] == pytest.approx(-0.05)

    def test_both_called_metal_is_not_separated(self):  # the gold-like dielectric at 0.99, gold 0.98
        s = score_pairs([METAL], means(d=(0.2, 0.99), x=(0.2, 0.98)))
        assert s["metal"]["separated"] == 0.0

    def test_separation_needs_each_side_of_the_threshold(self):
        assert score_pairs([METAL], means(d=(0, 0.5), x=(0, 0.9)))["metal"]["separated"] == 0.0
        assert score_pairs([METAL], means(d=(0, 0.1), x=(0, 0.5)))["metal"]["separated"] == 0.0
        assert score_pairs([METAL], means(d=(0, 0.1), x=(0, 0.5)), threshold=0.4)["metal"]["separated"] == 1.0

    def test_fractions_over_several_pairs_and_a_kind_without_pairs(self):
        other = {**ROUGH, "id": "c02", "scenes": {"glossy": "g2", "matte": "m2"}}
        s = score_pairs([ROUGH, other], means(g=(0.1, 0), m=(0.8, 0), g2=(0.5, 0), m2=(0.4, 0)))
        assert s["roughness"]["ordered"] == 0.5 and s["metal"] == {"pairs": 0, "separated": None}

    def test_table_has_a_row_per_pair_and_the_fractions(self):
        table = pairs_table(score_pairs([ROUGH, METAL], means(g=(0.21, 0), m=(0.16, 0), d=(0.2, 0.99),
                                                                   x=(0.2, 0.98))))
        assert "| c00 | roughness | sphere | glossy 0.21, 0.00 | matte 0.16, 0.00 | gap -0.05: inverted |" in table
        assert "not separated at 0.5" in table
        assert "glossy/matte pairs ordered: 0 % of 1" in table and "separated at 0.5: 0 % of 1" in table


def _scene(root: Path, name: str, mask: np.ndarray) -> None:
    """A GT scene with two test views of 4 x 4 px and the given foreground."""
    views = [{"id": v, "K": [[4, 0, 2], [0, 4, 2], [0, 0, 1]], "w2c": np.eye(4).tolist()} for v in ("t00", "t01")]
    (root / name).mkdir(parents=True)
    (root / name / "scene.json").write_text(json.dumps({
        "format": "gspi-scene", "format_version": 1, "name": name, "width": 4, "height": 4,
        "camera_convention": "opencv", "capture_env": "e", "relight_envs": [], "views": {"test": views}}))
    for v in ("t00", "t01"):
        (root / name / "test" / v).mkdir(parents=True)
        write_png(root / name / "test" / v / "mask.png", mask[..., None])


def _prediction(run: Path, name: str, roughness: np.ndarray, metallic: float, views=("t00", "t01")) -> None:
    for v in views:
        d = run / "predictions" / name / "test" / v
        d.mkdir(parents=True)
        write_png(d / "roughness.png", roughness[..., None])
        write_png(d / "metallic.png", np.full((4, 4, 1), metallic, np.float32))


@pytest.fixture
def dataset_and_run(tmp_path):
    data, run = tmp_path / "data", tmp_path / "run"
    mask = np.zeros((4, 4), np.float32)
    mask[:2] = 1.0  # the top half is the object
    for name in ("g", "m", "d", "x"):
        _scene(data, name, mask)
    write_manifest(data, 0, [ROUGH, METAL])
    top = np.full((4, 4), 1.0, np.float32)  # background at 1.0 must not count
    _prediction(run, "g", np.where(mask > 0, 0.2, 1.0).astype(np.float32), 0.0)
    _prediction(run, "m", np.where(mask > 0, 0.6, 0.0).astype(np.float32), 0.0)
    _prediction(run, "d", top * 0.4, 0.2)
    _prediction(run, "x", top * 0.4, 0.8)
    return data, run


def test_masked_means_pool_the_foreground_of_every_view(dataset_and_run):
    data, run = dataset_and_run
    assert masked_means(data / "g", run / "predictions" / "g") == pytest.approx({"roughness": 0.2, "metallic": 0.0},
                                                                                 abs=1e-4)
    assert masked_means(data / "m", run / "predictions" / "m")["roughness"] == pytest.approx(0.6, abs=1e-4)


def test_missing_prediction_names_the_file(dataset_and_run):
    data, run = dataset_and_run
    (run / "predictions" / "x" / "test" / "t01" / "metallic.png").unlink()
    with pytest.raises(ValueError, match="t01/metallic.png: missing"):
        masked_means(data / "x", run / "predictions" / "x")


def test_script_prints_the_table_and_writes_the_scores(dataset_and_run, tmp_path, capsys):
    data, run = dataset_and_run
    assert main([str(run), "--data", str(data), "--json", str(tmp_path / "s.json")]) == 0
    scores = json.loads((tmp_path / "s.json").read_text())
    assert scores["roughness"] == {"pairs": 1, "ordered": 1.0, "ordered_with_gap": 1.0}
    assert scores["metal"]["separated"] == 1.0
    assert "| c01 | metal | torus |" in capsys.readouterr().out


def test_scores_record_the_runs_overrides(dataset_and_run):
    data, run = dataset_and_run
    (run / ".hydra").mkdir()
    (run / ".hydra" / "overrides.yaml").write_text("- recon=fast\n- recon.lr.shN=0.0025\n")
    scores = score_run(run, data)
    assert scores["overrides"] == ["recon=fast", "recon.lr.shN=0.0025"] and scores["data_overrides"] is None


def test_a_subset_of_pairs_needs_only_its_scenes(dataset_and_run):
    data, run = dataset_and_run
    import shutil

    shutil.rmtree(run / "predictions" / "d")
    scores = score_run(run, data, pair_ids=["c00"])
    assert [r["id"] for r in scores["pairs"]] == ["c00"] and scores["metal"]["pairs"] == 0
    with pytest.raises(ValueError, match="no pairs"):
        score_run(run, data, pair_ids=["c07"])


def test_docs_show_the_committed_scores():
    """docs/results/controlled_pairs.md's tables are the committed scores' pairs_table, and docs/STAGE2.md's
    summary has a row per run with its shares (generated by make results: gspi.publish; tests/test_docs_results.py
    checks that both are current)."""
    from gspi.publish.docs import PAIRS_RUNS

    results = sorted((REPO / "results" / "controlled_pairs" / "cpu").glob("*.json"))
    assert results, "no committed controlled-pairs scores"
    pairs = (REPO / "docs" / "results" / "controlled_pairs.md").read_text()
    summary = (REPO / "docs" / "STAGE2.md").read_text()
    for path in results:
        scores = json.loads(path.read_text())
        assert pairs_table(scores) in pairs, f"docs/results/controlled_pairs.md lacks {path.name}'s table"
        row = next(line for line in summary.splitlines() if line.startswith(f"| {PAIRS_RUNS[path.stem]} |"))
        assert f"| {scores['metal']['pairs']} | {100 * scores['metal']['separated']:.0f} % |" in row


def test_script_states_a_missing_scene_in_one_line(dataset_and_run, capsys):
    data, run = dataset_and_run
    import shutil

    shutil.rmtree(run / "predictions" / "d")
    assert main([str(run), "--data", str(data)]) == 1
    assert "missing" in capsys.readouterr().err


def test_a_committed_pairs_run_must_say_what_it_is(tmp_path, monkeypatch):
    import gspi.publish.docs as docs

    (tmp_path / "mystery.json").write_text("{}")
    monkeypatch.setattr(docs, "PAIRS", tmp_path)
    with pytest.raises(ValueError, match=r"\['mystery'\] not in gspi.publish.docs.PAIRS_RUNS"):
        docs.controlled_pairs_block()

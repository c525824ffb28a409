import json

import pytest

from experiments.known_light import end_to_end as e2e


def test_lead_counts_the_scenes_both_have():
    a = {"s1": {"albedo": 20.0}, "s2": {"albedo": 10.0}, "s3": {"albedo": 30.0}}
    b = {"s1": {"albedo": 18.0}, "s2": {"albedo": 13.0}}
    assert e2e.lead(a, b, "albedo") == (pytest.approx(-0.5), 1, 2)


def test_collect_copies_each_method_with_portable_paths(tmp_path, monkeypatch):
    monkeypatch.setattr(e2e, "OUT", tmp_path / "out")
    runs = tmp_path / "work" / "runs"
    meta = {"data": str(tmp_path / "work" / "data"), "per_scene": {"s1": {c: {"psnr": 12.0} for c in e2e.CHANNELS}}}
    for method in ("light_fit", "no_decomposition"):
        (runs / f"method={method}" / "eval").mkdir(parents=True)
        (runs / f"method={method}" / "eval" / "eval_meta.json").write_text(json.dumps(meta))
        (runs / f"method={method}" / "eval" / "summary.json").write_text(json.dumps({"metallic": {"iou": 0.5}}))
    written = e2e.collect("pathtraced", runs)
    assert len(written) == 4
    copied = json.loads((tmp_path / "out" / "pathtraced" / "method=light_fit" / "eval" / "eval_meta.json").read_text())
    assert copied["data"] == "<work>/data"
    assert e2e.per_scene("pathtraced", "light_fit") == {"s1": {c: 12.0 for c in e2e.CHANNELS}}
    assert e2e.per_scene("pathtraced", "gspi") is None


def test_collect_names_a_folder_without_runs(tmp_path):
    with pytest.raises(SystemExit, match="no method=<name>/eval/eval_meta.json"):
        e2e.collect("pathtraced", tmp_path)


def test_prior_rows_lead_over_the_methods_of_the_variant_they_repeat(tmp_path, monkeypatch):
    monkeypatch.setattr(e2e, "OUT", tmp_path)

    def write(variant, method, psnr):
        folder = tmp_path / variant / f"method={method}" / "eval"
        folder.mkdir(parents=True)
        per_scene = {s: {c: {"psnr": psnr + i} for c in e2e.CHANNELS} for i, s in enumerate(("s1", "s2"))}
        (folder / "eval_meta.json").write_text(json.dumps({"per_scene": per_scene}))
        (folder / "summary.json").write_text(json.dumps({"metallic": {"iou": 0.25}}))

    write("polyhaven_capture_prior", "gspi", 15.0)
    write("polyhaven_capture", "gspi", 14.0)
    write("polyhaven_capture", "light_fit", 16.5)
    rows = e2e.prior_table()
    assert f"| {e2e.VARIANTS['polyhaven_capture']} (2 scenes) | {e2e.PRIOR} | 15.50 | 15.50 | 15.50 | 15.50 | 0.25 |" in rows
    assert "| polyhaven_capture_prior | GS-PI's default | +1.00 (2/2) | +1.00 (2/2) | +1.00 (2/2) | +1.00 (2/2) |" in rows
    assert "| polyhaven_capture_prior | light_fit | -1.50 (0/2) | -1.50 (0/2) | -1.50 (0/2) | -1.50 (0/2) |" in rows
    assert not any("no_decomposition" in r for r in rows)


def test_no_prior_run_no_prior_table(tmp_path, monkeypatch):
    monkeypatch.setattr(e2e, "OUT", tmp_path)
    assert e2e.prior_table() == []


def test_prior_on_the_real_objects_leads_over_the_default_s_card_means(tmp_path, monkeypatch):
    monkeypatch.setattr(e2e, "OUT", tmp_path)
    monkeypatch.setattr(e2e, "card_row", lambda: {c: 10.0 for c in e2e.CHANNELS})
    folder = tmp_path / "real_objects_prior" / "method=gspi" / "eval"
    folder.mkdir(parents=True)
    per_scene = {"a": {c: {"psnr": 12.0} for c in e2e.CHANNELS}, "b": {c: {"psnr": 13.0} for c in e2e.CHANNELS}}
    (folder / "eval_meta.json").write_text(json.dumps({"per_scene": per_scene}))
    rows = e2e.prior_table()
    assert ("| real_objects_prior | GS-PI's default (its card, seed 0; means only) | +2.50 | +2.50 | +2.50 | +2.50 |"
            in rows)

"""Issue 52 probes' pure helpers: the cue oracle's (cue_oracle.py) and the pair highlights' (pair_highlights.py)."""
import numpy as np
import pytest

from experiments.view_dependence.cue_oracle import nested_subsets


def test_nested_subsets_grow_by_adding_scenes_and_are_seeded():
    names = [f"s{i:03d}" for i in range(40)]
    subsets = nested_subsets(names, [8, 16, 40], seed=0)
    assert [len(subsets[n]) for n in (8, 16, 40)] == [8, 16, 40]
    assert set(subsets[8]) <= set(subsets[16]) <= set(subsets[40]) == set(names)
    assert subsets == nested_subsets(names, [8, 16, 40], seed=0)
    assert subsets[8] != nested_subsets(names, [8], seed=1)[8]
    with pytest.raises(ValueError, match="asks for 41 training scenes, the folder has 40"):
        nested_subsets(names, [41], seed=0)


def test_highlight_summary_counts_the_points_above_the_gain():
    from experiments.view_dependence.pair_highlights import HIGHLIGHT_GAIN, highlight_summary

    gain = np.array([0.0, 0.01, 0.02, HIGHLIGHT_GAIN, 0.5, 3.0])  # the threshold itself is not a highlight
    out = highlight_summary(gain)
    assert out["share_highlit"] == pytest.approx(2 / 6)
    assert out["median"] == pytest.approx(np.median(gain))
    assert out["q90"] == pytest.approx(np.quantile(gain, 0.9))


def test_object_features_pool_the_whole_object_for_every_point():
    from experiments.view_dependence.cue_oracle import object_features

    features = np.array([[0.0, 1.0], [1.0, 1.0], [2.0, 1.0], [3.0, 5.0]])
    gain = np.array([0.0, 0.1, 0.5, 2.0])
    out = object_features(features, gain)  # HIGHLIGHT_GAIN 0.2: two of the four points highlit
    assert out.shape == (4, 5)
    np.testing.assert_allclose(out, np.broadcast_to(out[0], out.shape))  # one row for all points
    np.testing.assert_allclose(out[0, :2], [1.5, 2.0])                      # means
    np.testing.assert_allclose(out[0, 2:4], np.quantile(features, 0.9, axis=0), rtol=1e-6)
    assert out[0, 4] == pytest.approx(0.5)                                  # 2 of 4 points highlit


def test_evaluate_reports_each_predicted_scenes_mean_and_needs_one_fold():
    from experiments.view_dependence.cue_oracle import evaluate

    rng = np.random.default_rng(0)

    def scene(rough: float) -> dict:
        n = 50
        cue = np.full((n, 1), rough, dtype=np.float32)  # a feature that is the target: learnable
        return {"top_rgb": cue, "onehot": np.zeros((n, 2), np.float32), "cross_view": cue,
                "cross_view_object": cue, "roughness": np.full(n, rough, np.float32),
                "metallic": (rng.random(n) > 0.5).astype(np.float32), "multi_part": np.zeros(n, bool)}

    version = {f"p{i:04d}_sphere_metal": scene(r) for i, r in enumerate([0.1, 0.9, 0.2, 0.8])}
    predict = {"glossy": scene(0.1), "matte": scene(0.9)}
    out = evaluate(version, [(sorted(version)[:2], sorted(version)[2:])], steps=300,
                   feature_sets=["R1 + cross-view + object"], predict=predict)
    means = out["R1 + cross-view + object"]["scene_means"]
    assert set(means) == {"glossy", "matte"} and means["glossy"]["roughness"] < means["matte"]["roughness"]
    gain = out["R1 + cross-view + object"]["roughness_scene_gain"]
    assert gain["scenes"] == 2 and gain["ci95"][0] <= gain["mean"] <= gain["ci95"][1]
    # roughness 0.2 and 0.8 against the training mean 0.5: the constant's per-scene PSNR is 10.46 dB;
    # a reader of the cue beats it on both test scenes, so even the CI's lower end is above 0
    assert gain["ci95"][0] > 0
    with pytest.raises(ValueError, match="needs one fold"):
        evaluate(version, [(["p0000_sphere_metal"], ["p0001_sphere_metal"])] * 2, steps=1, predict=predict)


def test_real_objects_table_calls_a_model_ahead_only_above_no_decomposition_on_every_channel():
    from experiments.view_dependence.probe_tables import REAL_CHANNELS, real_objects_table

    def run(**psnr):  # two objects with the same scores per channel
        return {"per_scene": {o: {c: {"psnr": psnr.get(c, 10.0)} for c in REAL_CHANNELS}
                              for o in ("Avocado", "WaterBottle")}}

    card = {"no_decomposition_same_data": dict.fromkeys(REAL_CHANNELS, 9.0),
            "seed0": {"mean_psnr": dict.fromkeys(REAL_CHANNELS, 12.0), "WaterBottle_metallic_psnr": 4.0}}
    runs = {"table2_cpu_x__full_s0": run(albedo=11.0, roughness=11.0, metallic=11.0, relight=11.0),
            "table2_cpu_x__full_s1": run(albedo=11.0, roughness=11.0, metallic=11.0, relight=10.0)}
    text = real_objects_table(runs, run(), card, "stage2_x")
    rows = {line.split(" | ")[0].strip("| "): line for line in text.splitlines() if line.startswith("| retrained")
            or line.startswith("| `stage2_x")}
    assert rows["retrained table2_cpu_x/full_s0"].endswith("| 11.00 | yes |")   # WaterBottle metallic 11
    assert rows["retrained table2_cpu_x/full_s1"].endswith("| no (relight behind) |")  # a tie is not ahead
    assert rows["`stage2_x.pt` (default), seed 0"].endswith("| 4.00 | yes |")
    assert text.startswith("The 2 real objects")
    with pytest.raises(ValueError, match="scores 1 objects, no decomposition's 2"):
        real_objects_table({"a__b": {"per_scene": {"Avocado": run()["per_scene"]["Avocado"]}}}, run(), card, "stage2_x")


def test_paired_difference_pairs_scenes_of_the_same_training_seed_only():
    from experiments.view_dependence.probe_tables import paired_difference

    def run(seed, rough):  # three scenes; albedo and metallic fixed
        return {"train_seed": seed, "per_scene": {"stage2": {
            s: {"albedo": {"psnr": 10.0}, "roughness": {"psnr": r}, "metallic": {"psnr": 20.0}}
            for s, r in zip(("a", "b", "c"), rough)}}}

    ref = [run(0, (10.0, 12.0, 14.0)), run(1, (11.0, 13.0, 15.0))]
    # every scene 1 dB better than the same seed's: the difference is exactly +1 with no spread
    better = [run(1, (12.0, 14.0, 16.0)), run(0, (11.0, 13.0, 15.0))]
    diff = paired_difference(better, ref)
    assert diff["roughness"] == "+1.00 [+1.00, +1.00]"
    assert diff["avg"] == "+0.33 [+0.33, +0.33]" and diff["metallic"] == "+0.00 [+0.00, +0.00]"
    # a seed with no reference is left out, not paired with another seed
    assert paired_difference([run(2, (0.0, 0.0, 0.0)), better[1]], ref)["roughness"] == "+1.00 [+1.00, +1.00]"

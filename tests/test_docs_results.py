"""`make results` (gspi/publish/docs.py): every committed result table equals what the
command generates from the committed scores, and the generator fails loudly on broken markers."""
import pytest

from gspi.publish import docs as docs_results
from tests.machine_paths import MACHINE_PATH


def test_committed_tables_equal_the_generated_ones():
    stale = [str(p.relative_to(docs_results.ROOT)) for p, text in docs_results.generated().items()
             if not p.is_file() or p.read_text() != text]
    assert not stale, f"run `make results` and commit: {stale}"


def test_a_block_is_replaced_between_its_markers_only():
    text = "a\n<!-- generated: t -->\nold 1.00\n<!-- /generated: t -->\nb\n"
    assert docs_results.replace_block(text, "t", "new\n", "X") == \
        "a\n<!-- generated: t -->\nnew\n<!-- /generated: t -->\nb\n"
    with pytest.raises(ValueError, match="X: needs exactly one"):
        docs_results.replace_block("no markers", "t", "new\n", "X")


def test_check_exits_1_naming_a_stale_file(tmp_path, monkeypatch, capsys):
    target = tmp_path / "t.md"
    target.write_text("typed by hand\n")
    monkeypatch.setattr(docs_results, "generated", lambda: {target: "generated\n"})
    monkeypatch.setattr(docs_results, "ROOT", tmp_path)
    assert docs_results.main(["--check"]) == 1 and "t.md" in capsys.readouterr().out
    assert target.read_text() == "typed by hand\n"  # --check writes nothing
    assert docs_results.main([]) == 0 and target.read_text() == "generated\n"
    assert docs_results.main(["--check"]) == 0


def test_table2_is_built_from_the_reproduce_commands_committed_scores():
    """docs/results/table2.md reads gspi-reproduce's committed scores (one folder per variant and
    seed): every folder is a row's unit, and none of them names a machine path."""
    text = docs_results.table2_file()
    folders = sorted(p.parent.name for p in docs_results.TABLE2_SCORES.glob("*/scores.json"))
    assert {"full_s0", "a2_no_view_onehot_s0"} <= set(folders)
    assert all(name in text for name in folders) and not MACHINE_PATH.search(text)


def test_models_of_heldout_files():
    assert docs_results.model_of("cpu_parts_pool_pixel_5k_224_s1") == docs_results.DEFAULT_MODEL
    assert docs_results.model_of("cpu_parts_pool_a1_no_global_prior_pixel_5k_224_s0") == ""
    assert docs_results.model_of("stage2_pool224") == "stage2_pool224"


def test_no_generated_number_is_typed_in_the_docs_that_link_to_it():
    """The default's held-out average appears only in the generated file (and the diary, history)."""
    heldout = (docs_results.ROOT / "docs" / "results" / "heldout.md").read_text()
    row = next(line for line in heldout.splitlines() if "**default**" in line)
    average = row.split("|")[6].strip()
    for doc in ("README.md", "docs/STAGE2.md", "checkpoints/README.md", "docs/RESULTS.md"):
        assert average not in (docs_results.ROOT / doc).read_text(), doc


def test_the_default_is_the_best_held_out_candidate_that_passes_the_rule():
    from eval.tables.cards import rule_failures

    cards = docs_results._cards()
    passing = [c for c in cards if not rule_failures(c)]
    assert max(passing, key=lambda c: c.heldout_avg).model == docs_results.DEFAULT_MODEL
    assert any(rule_failures(c) for c in cards)  # the rule rejects someone (stage2_parts_pool: roughness)


def test_every_candidate_card_is_read_with_both_seeds():
    for card in docs_results._cards():
        assert len(card.s004_iou) == len(card.s004_metallic) == len(card.real) >= 2, card.model
        assert set(card.real[0]) >= {"albedo", "roughness", "metallic", "relight"}, card.model


def test_table2_says_which_planned_runs_are_not_measured_yet():
    line = docs_results.runs_line(["full_s0", "full_s1", "a1_s0"], ["full", "a1", "a4"], [0, 1], "plan.yaml", "go on")
    assert line == ("- Runs measured: 3 of the 6 that plan.yaml plans (3 variants x seeds 0, 1); not yet: a1 s1; "
                    "a4 (none yet). `go on` goes on with them.")
    assert docs_results.runs_line(["a_s0"], ["a"], [0], "p", "c") == "- Runs measured: 1 of the 1 that p plans (1 variants x seeds 0)."
    # variant_seeds: a variant planned at some seeds only is counted at those
    line = docs_results.runs_line(["a_s0", "a_s1", "b_s0"], ["a", "b"], [0, 1], "p", "c", variant_seeds={"b": [0]})
    assert line == "- Runs measured: 3 of the 3 that p plans (2 variants x seeds 0, 1; b at seeds 0)."


def test_table2_names_what_a_variant_changes_at_this_scale():
    line = docs_results.departures_line({"a4": ["stage2.model.num_latents=48"], "a1": ["x=1", "y=2"]}, "p.yaml")
    assert line == ("- Beyond its ablation config, at this scale (p.yaml, `variant_overrides`): "
                    "a4: stage2.model.num_latents=48; a1: x=1, y=2.")
    assert docs_results.departures_line({}, "p.yaml") == ""
    assert "a4_npts_1024_nlat_384: stage2.model.num_latents=48" in docs_results.table2_file()


def test_each_reproduce_file_commits_where_the_publisher_reads():
    """A committed ``scores_dir`` of conf/reproduce/<table>_<scale>.yaml is the store's folder of that
    table and scale (gspi.publish.store.table_folder): the two names of one place cannot drift."""
    import yaml

    from gspi.publish.store import table_folder
    from gspi.repo import REPO

    committed = {}
    for path in sorted((REPO / "conf" / "reproduce").glob("*.yaml")):
        scores_dir = str(yaml.safe_load(path.read_text()).get("scores_dir", ""))
        if scores_dir.startswith("results/"):
            table, scale = path.stem.rsplit("_", 1)
            committed[path.name] = (scores_dir, str(table_folder(table, scale).relative_to(REPO)))
    assert {"table1_cpu.yaml", "table2_cpu.yaml"} <= set(committed)
    assert {name: a for name, (a, b) in committed.items() if a != b} == {}

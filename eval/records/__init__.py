"""The on-disk formats the evaluator owns, one module each (its file names, version,
completeness rule, writer and reader):

* ``eval_folder``: a `gspi-eval` folder (per_view.csv, eval_meta.json, summary.json last);
* ``run_record``: a `gspi-run` job's ``result.json`` (docs/TABLES.md, "Run record");
* ``run_points``: a job's ``points_eval/points_summary.json`` (Table 2 on its generated clouds);
* ``points_scores``: Table 2's point-level ``scores.json`` (format gspi-points-eval).
"""

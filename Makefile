# The two set-up commands: `make repro` and `make test`. Both create .venv on first use.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(CURDIR)/$(VENV)/bin
STAMP := $(VENV)/.installed
TEST_STAMP := $(VENV)/.installed-test
export PATH := $(BIN):$(PATH)

.PHONY: install repro test lint ui frames chromium docs-report clean-venv

# uv installs in about 25 s what pip took 2 min for. It does not read pip's config, so it is told where a machine keeps
# its CPU build of torch (TORCH_WHEELS, where that folder exists): without it, torch==2.13.0 from PyPI is the CUDA
# build, 3 GB more to download and 2-3 s more to import in every stage and test process. uv byte-compiles nothing;
# Python compiles the modules it actually imports on first use, once.
TORCH_WHEELS ?= /opt/wheels
UV_INSTALL = $(BIN)/uv pip install --quiet --system-certs --python $(BIN)/python \
	$(if $(wildcard $(TORCH_WHEELS)/torch-*.whl),--find-links $(TORCH_WHEELS))

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet uv==0.13.9
	$(UV_INSTALL) -e .
	$(BIN)/uqdrive plots-page --out .dvc/plots_page.html  # Vega inlined: `dvc plots show` draws offline
	$(BIN)/dvc config --local plots.html_template plots_page.html  # this checkout's (.dvc/config.local); without it DVC's own page
	touch $(STAMP)

$(TEST_STAMP): $(STAMP)
	$(UV_INSTALL) -e '.[test]'
	touch $(TEST_STAMP)

install: $(STAMP)

repro: $(STAMP)
	dvc repro
	@echo "Report: reports/report.html (and report.md). Metrics: metrics/, figures: plots/, data: data/, models: models/."
	@echo "Runs in MLflow: make ui"

# Two pytest workers, a test file to each in turn (pyproject addopts): the `dvc repro` test runs beside the rest.
test: lint
	pytest -q --durations=20

lint: $(TEST_STAMP)
	ruff check src stages tests
	ruff format --check src stages tests

# Debian's Chromium for the browser test of `dvc plots show`'s page (tests/test_plots_page.py; skipped without it,
# failed in CI). apt needs root; nothing is downloaded at test time.
chromium:
	command -v chromium >/dev/null || { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium; }

# `make ui PORT=5001` where 5000 is taken
PORT ?= 5000
ui: $(STAMP)
	@echo "MLflow UI on the project's runs (mlflow.db, artefacts in mlartifacts/): http://127.0.0.1:$(PORT)/#/experiments?workflowType=machine_learning  (Ctrl-C stops it); each experiment's runs with its key metrics as columns:"
	@$(BIN)/python -c 'from uqdrive.tracking import follow_project; follow_project(".", $(PORT))'
	mlflow ui --host 127.0.0.1 --backend-store-uri sqlite:///$(CURDIR)/mlflow.db --default-artifact-root $(CURDIR)/mlartifacts --port $(PORT)

frames: $(STAMP)
	uqdrive frames --out docs/frames
	uqdrive frames --compare-render 160x120 --out docs/frames

# the committed run's report for docs/ (after `make repro`): its figures on 256-colour palettes, under 2 MB
docs-report: $(STAMP)
	$(BIN)/python -m uqdrive.tools.docs_report reports/report.html docs/report.html

clean-venv:
	rm -rf $(VENV)

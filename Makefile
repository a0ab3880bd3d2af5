# The two set-up commands: `make repro` and `make test`. Both create .venv on first use.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(CURDIR)/$(VENV)/bin
STAMP := $(VENV)/.installed
export PATH := $(BIN):$(PATH)

.PHONY: install repro test ui frames clean-venv

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

repro: $(STAMP)
	dvc repro
	@echo "Outputs: data/raw/ (collected episodes), data/processed/ (train/val), metrics/, plots/; runs in MLflow: make ui"

test: $(STAMP)
	pytest -q

ui: $(STAMP)
	mlflow ui --backend-store-uri sqlite:///$(CURDIR)/mlflow.db --default-artifact-root $(CURDIR)/mlartifacts --port 5000

frames: $(STAMP)
	uqdrive frames --out docs/frames

clean-venv:
	rm -rf $(VENV)

# Two entry points for a fresh machine (see README):
#   make reproduce   set up .venv, then `dvc repro`: every table and figure from the committed checkpoints
#   make test        set up .venv, then the test suite
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: setup reproduce test bench regenerate

setup: $(STAMP)

# torch first and pinned: an unpinned torch pulls several GB of CUDA wheels (../shared/NOTES.md).
$(STAMP): environment.lock pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -r environment.lock
	$(BIN)/pip install -q --no-deps --no-build-isolation -e .
	touch $(STAMP)

reproduce: $(STAMP)
	PATH=$(CURDIR)/$(BIN):$$PATH $(BIN)/dvc repro

test: $(STAMP)
	PATH=$(CURDIR)/$(BIN):$$PATH $(BIN)/python -m pytest -n 2 -q tests

bench: $(STAMP)
	$(BIN)/python -m paper_lib.bench

# Every table and figure again from the committed checkpoints (nothing is retrained).
regenerate: $(STAMP)
	PATH=$(CURDIR)/$(BIN):$$PATH $(BIN)/dvc repro -f -s collect
	PATH=$(CURDIR)/$(BIN):$$PATH $(BIN)/dvc repro -f -s rewards ood uncertainty_over_time training_and_perturbations paper_vs_us

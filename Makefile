# Entry points for a fresh machine (see README):
#   make reproduce   set up .venv, then every table and figure from the committed runs and recordings
#                    (minutes; never steps an env: no training, collection or episode; lists the missing runs)
#   make test        set up .venv, then the test suite (CI runs exactly this: .ci/run)
#   make recollect   everything that simulates again (ID/OOD states, evaluation episodes, recordings, experiments), then reproduce (long)
#   make retrain     train every missing or changed run of the active profile, then everything (HOURS per run)
#   make verify      recompute the committed scores of one run per env aside and compare them, file by file
#   make render-deps install the EGL libraries MuJoCo's offscreen rendering needs (Debian/Ubuntu, as root)
#   make lab         JupyterLab on the project's .venv kernel, opened at notebooks/ (prints its address; Ctrl+C stops it)
#   make site        the results website from docs/ and the executed notebooks, offline: open build/site/index.html
#   make browser-deps install Debian's chromium and chromedriver, which the browser tests drive (as root; make test runs it)
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
WITH_VENV := PATH=$(CURDIR)/$(BIN):$$PATH

.PHONY: setup reproduce regenerate recollect retrain test bench verify render-deps lab site browser-deps

setup: $(STAMP)

# torch first and pinned: an unpinned torch pulls several GB of CUDA wheels.
$(STAMP): environment.lock pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -r environment.lock
	$(BIN)/pip install -q --no-deps --no-build-isolation -e .
	touch $(STAMP)

# Then the README's headline table and docs/results.md, docs/benchmarks.md and docs/deviations.md are pasted again from what the pipeline wrote.
reproduce: $(STAMP)
	$(WITH_VENV) $(BIN)/python -m paper_lib.pipeline.reproduce
	$(BIN)/python scripts/readme_results.py

# The former name of `reproduce`.
regenerate: reproduce

recollect: $(STAMP)
	$(WITH_VENV) $(BIN)/python -m paper_lib.pipeline.reproduce --recollect

retrain: $(STAMP)
	$(WITH_VENV) $(BIN)/python -m paper_lib.pipeline.reproduce --retrain

test: $(STAMP) browser-deps
	$(WITH_VENV) $(BIN)/python -m pytest -n 2 --dist loadfile --no-loadscope-reorder -q tests

# Same seed, same machine: same numbers. Writes nothing under results/ (paper_lib/pipeline/verify.py).
verify: $(STAMP)
	$(WITH_VENV) $(BIN)/python -m paper_lib.pipeline.verify

bench: $(STAMP)
	$(BIN)/python -m paper_lib.bench
	$(BIN)/python scripts/readme_results.py

# MuJoCo renders offscreen with EGL (MUJOCO_GL=egl); these Debian packages provide it. Skipped where
# apt-get is missing or we are not root: the notebooks then say that frames are unavailable.
render-deps:
	@if command -v apt-get >/dev/null && [ "$$(id -u)" = 0 ]; then \
		apt-get update -qq && apt-get install -y -qq libegl1 libopengl0 libegl-mesa0 libgl1-mesa-dri; \
	else \
		echo "render-deps: needs apt-get and root; install libegl1 libopengl0 libegl-mesa0 libgl1-mesa-dri yourself"; \
	fi

# The readers' front doors (scripts/lab.py, scripts/build_site.py; docs/pipeline.md). `make lab` starts kernels in
# the repository root, where the notebooks' paths resolve; `make site` shows the committed executed notebooks
# (nothing is executed or fetched) and rebuilds only what changed since the last build.
lab: $(STAMP)
	$(WITH_VENV) $(BIN)/python scripts/lab.py

site: $(STAMP)
	$(WITH_VENV) $(BIN)/python scripts/build_site.py

# tests/project/test_lab.py and tests/project/test_site.py drive Debian's chromium through chromedriver (Selenium
# never downloads a browser). Installed where missing, as root with apt-get (CI); elsewhere those tests skip with
# this advice.
browser-deps:
	@if command -v chromium >/dev/null && command -v chromedriver >/dev/null; then \
		:; \
	elif command -v apt-get >/dev/null && [ "$$(id -u)" = 0 ]; then \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
			chromium chromium-driver fonts-liberation \
		|| echo "browser-deps: apt-get could not install chromium; tests/project/test_lab.py and test_site.py will fail"; \
	else \
		echo "browser-deps: needs apt-get and root; install chromium and chromium-driver (Debian) yourself"; \
	fi

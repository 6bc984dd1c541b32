# The verbs users and CI call. Every target sets up its own virtual environment on first use.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
CONFIG ?= configs/quickstart.yaml
PYTEST_ARGS ?=

# `make sweep` runs every shipped config (or CONFIGS=...), one target each: results/<stem>/results.h5
# depends on configs/<stem>.yaml, so `make -j4 sweep` runs them side by side and an unchanged
# config is not run again (a changed one starts over: --force).
CONFIGS ?= $(wildcard configs/*.yaml)
RESULTS := $(patsubst configs/%.yaml,results/%/results.h5,$(CONFIGS))
REPORTS := $(patsubst configs/%.yaml,results/%/report.html,$(CONFIGS))

.PHONY: install install-test install-cholmod install-peers install-engines run test plot bench config-times sweep reports clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(VENV)/.installed-test: pyproject.toml $(VENV)/.installed
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $@

install: $(VENV)/.installed            ## create .venv and install simrun into it

install-test: $(VENV)/.installed-test  ## the same, with the test extras

# The optional `cholesky` linear solver: CHOLMOD through scikit-sparse, which compiles against
# SuiteSparse's headers; CHOLMOD's supernodal factorisation runs in BLAS, and Debian's default
# reference BLAS makes it ~3.5x slower than OpenBLAS (64x64 cloth: 208 ms instead of 59 ms).
SUITESPARSE_PACKAGES := libsuitesparse-dev libopenblas0-pthread
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
CHOLMOD_HELP := install SuiteSparse's headers and OpenBLAS yourself (Debian: $(SUITESPARSE_PACKAGES), and python3-dev for a Debian system Python), then run make install-cholmod again

install-cholmod: $(VENV)/.installed-cholmod  ## the optional CHOLMOD solver (Debian packages, then the extra)

$(VENV)/.installed-cholmod: pyproject.toml $(VENV)/.installed
	@if ! dpkg -s $(SUITESPARSE_PACKAGES) >/dev/null 2>&1; then \
	  if command -v apt-get >/dev/null 2>&1 && { [ -z "$(SUDO)" ] || command -v sudo >/dev/null 2>&1; }; then \
	    $(SUDO) apt-get install -y -q $(SUITESPARSE_PACKAGES) || \
	      { $(SUDO) apt-get update -q && $(SUDO) apt-get install -y -q $(SUITESPARSE_PACKAGES); }; \
	  elif [ ! -f /usr/include/suitesparse/cholmod.h ]; then \
	    echo "install-cholmod: cannot install system packages here: $(CHOLMOD_HELP)"; exit 1; \
	  fi; \
	fi
	$(BIN)/python -m pip install --quiet -e '.[cholmod]'
	touch $@

install-peers: $(VENV)/.installed-peers  ## the peers `make bench` compares with, where they install (Newton on Warp)

$(VENV)/.installed-peers: pyproject.toml $(VENV)/.installed
	$(BIN)/python -m pip install --quiet -e '.[peers]'
	touch $@

install-engines: $(VENV)/.installed-engines  ## the engines whose integrators simrun measures (MuJoCo, Newton; docs/engines.md)

$(VENV)/.installed-engines: pyproject.toml $(VENV)/.installed
	$(BIN)/python -m pip install --quiet -e '.[engines]'
	touch $@

run: install                           ## run the default experiment (CONFIG=... for another)
	$(BIN)/simrun $(CONFIG)

test: install-test                     ## run the whole test suite on both cores
	$(BIN)/python -m pytest -n auto $(PYTEST_ARGS)

plot: install                          ## redraw the default experiment's figures from its results file
	$(BIN)/simrun plot results/quickstart/results.h5

sweep: $(RESULTS)                      ## run every config in configs/ (CONFIGS=... for some), each once

# a config with a fit block is a calibration: `simrun fit` (docs/calibration.md); the others are run
results/%/results.h5: configs/%.yaml | $(VENV)/.installed
	$(BIN)/simrun $(if $(shell grep -l '^fit:' $<),fit,run) $< --output results/$* --force -q

reports: $(REPORTS)                    ## an HTML report beside each sweep's results

results/%/report.html: results/%/results.h5
	$(BIN)/simrun report $<

clean:                                 ## remove results and caches (keeps .venv)
	rm -rf results/*/ .pytest_cache .hypothesis
	find . -name __pycache__ -type d -prune -not -path './$(VENV)/*' -exec rm -rf {} +

bench: install                         ## speed benchmarks: one table of ratios (never part of `make test`)
	$(BIN)/python -m benchmarks

config-times: install                  ## each shipped config timed whole with -j 2 from a cold cache (CONFIGS=...: some)
	$(BIN)/python -m benchmarks.config_times $(if $(filter command line,$(origin CONFIGS)),$(CONFIGS),)

# Two entry points for a fresh machine: `make demo` and `make test`.
# Each creates .venv when needed and installs the project into it.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
OUT ?= carfeel-demo

.PHONY: demo test check lint docs bench mutate clean chromium

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(VENV)/.installed-test: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test,dev,docs,logs,batch,fmu,panel,pandas]'
	touch $(VENV)/.installed $@

demo: $(VENV)/.installed
	$(BIN)/carfeel demo --out-dir $(OUT)

lint: $(VENV)/.installed-test
	$(BIN)/ruff check src tests benchmarks docs examples
	$(BIN)/ruff format --check src tests benchmarks docs examples
	$(BIN)/mypy

# The panel's browser tests drive Debian's chromium (Playwright cannot download a browser here).
CHROMIUM ?= /usr/bin/chromium
chromium:
	@if [ ! -x $(CHROMIUM) ]; then \
		if [ "$$(id -u)" = 0 ]; then apt-get update -qq && apt-get install -y -qq chromium; \
		else echo "make: $(CHROMIUM) is missing and this is not root: the panel's browser tests" \
			"will be skipped (as root: apt-get install chromium)"; fi; \
	fi

test: lint chromium
	command -v cc >/dev/null || (apt-get update && apt-get install -y gcc)  # FMU export's compiler
	command -v cmake >/dev/null || (apt-get update && apt-get install -y cmake)  # FMPy's build
	$(BIN)/python -m pytest

# The fast tier, before each commit: lint, types and every test not marked slow (the matrices'
# many simulated runs, the browser, any test over 2 s): 130 s here; `make test` (and CI) runs them all.
check: lint
	command -v cc >/dev/null || (apt-get update && apt-get install -y gcc)
	command -v cmake >/dev/null || (apt-get update && apt-get install -y cmake)
	$(BIN)/python -m pytest -m "not slow" -q -n 2

# The documentation site (mkdocs.yml, docs/): built offline, every warning an error.
docs: $(VENV)/.installed-test
	$(BIN)/mkdocs build --strict -d site

bench: $(VENV)/.installed-test
	$(BIN)/python benchmarks/bench_engagement_step.py
	$(BIN)/python benchmarks/bench_steering.py
	$(BIN)/python benchmarks/bench_hpattern_step.py
	$(BIN)/python benchmarks/bench_loop.py
	$(BIN)/python benchmarks/bench_stability.py
	$(BIN)/python benchmarks/bench_fit.py
	$(BIN)/python benchmarks/bench_fit_bias.py
	$(BIN)/python benchmarks/bench_shift_fit.py
	$(BIN)/python benchmarks/bench_physical_fit.py
	$(BIN)/python benchmarks/bench_sweep.py
	$(BIN)/python benchmarks/bench_fmu.py
	$(BIN)/python benchmarks/bench_panel.py

# Mutation testing (mutmut) of the models, the rendering and the safety chain ([tool.mutmut] in
# pyproject.toml); MUTANTS="carfeel.realtime.safety*" narrows it. Hours on two cores for all of
# it: run it on what a change touched, and read `mutmut results` / `mutmut show NAME`.
MUTANTS ?=
mutate: $(VENV)/.installed-test
	$(BIN)/python -m pip install --quiet 'mutmut==3.8.1'
	$(BIN)/mutmut run --max-children 2 $(MUTANTS)
	$(BIN)/mutmut results

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache .mypy_cache .ruff_cache mutants

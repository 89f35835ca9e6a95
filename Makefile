# shoha: two commands from a fresh clone (README "Quickstart").
#   make demo   create .venv, install, run the main job on the built-in mini scene
#   make test   install the test extras and run the tests
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   := .venv
BIN    := $(VENV)/bin
OUT    := out

.PHONY: demo test test-slow bench lint screenshots clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# The search's compiled loops are compiled and cached once here, not in a first run's time limit.
$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	$(BIN)/python -m optimizer.search._contact
	touch $@

$(VENV)/.installed-test: pyproject.toml $(VENV)/.installed
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $@

$(VENV)/.installed-bench: pyproject.toml $(VENV)/.installed-test
	$(BIN)/python -m pip install --quiet -e '.[test,bench]'
	touch $@

demo: $(VENV)/.installed
	mkdir -p $(OUT)
	$(BIN)/shoha scene info mini
	$(BIN)/shoha optimize mini --out $(OUT)/mini.json --seed 1
	$(BIN)/shoha check $(OUT)/mini.json
	$(BIN)/shoha settle $(OUT)/mini.json
	$(BIN)/shoha render $(OUT)/mini.json --out $(OUT)/mini.png
	$(BIN)/shoha score $(OUT)/mini.json --reference $(OUT)/mini.json --html $(OUT)/mini-report.html
	@echo "open $(OUT)/mini-report.html in a browser; $(OUT)/mini.png for print"

# Two workers, each taking whole test files (their module fixtures are built once): 6 min on
# 2 cores against 11 min on one (398 s on a clean clone at 4aa94cb, 2026-12-06); 11-12 min on a
# slower 2-core machine without AVX-512 (651-735 s, 2026-11-29: 651 s for 773 tests on a clean
# clone at 3f998b7). PYTEST_WORKERS=0 runs in one process.
PYTEST_WORKERS ?= 2
test: $(VENV)/.installed-test
	$(BIN)/python -m pytest -q -n $(PYTEST_WORKERS) --dist loadfile

test-slow: $(VENV)/.installed-test
	$(BIN)/python -m pytest -q -m slow

# Every benchmark in benchmarks/ (docs/benchmarks.md); results in benchmarks/results/.
# About 27 minutes on 2 cores (26.8 min in benchmarks/results/run_all.csv).
bench: $(VENV)/.installed-bench
	$(BIN)/python benchmarks/run_all.py

# The README's pictures: the browser tests' screenshots, copied to docs/.
screenshots: $(VENV)/.installed-test
	$(BIN)/python -m pytest -q -m browser tests --screenshots docs

lint: $(VENV)/.installed-test
	$(BIN)/ruff check geometry settle optimizer benchmarks tests
	$(BIN)/lint-imports

clean:
	rm -rf $(VENV) $(OUT) build *.egg-info

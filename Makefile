# Two commands a newcomer needs: `make demo` and `make test`. Each builds .venv on first use.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-$(shell cat pyproject.toml | cksum | cut -d' ' -f1)

.PHONY: demo test test-slow bench bench-all reproduce lint docs clean venv

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet -e '.[test]'
	rm -f $(VENV)/.installed-*
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(BIN)/rulkit demo --out demo-out

# --dist worksteal: a worker that runs out of tests takes half of the other's queue, so the
# run does not end with one worker idle behind long tests queued late on the other. The 20
# slowest tests are printed so that a test eating into the budget is seen in every run.
test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/mypy
	$(BIN)/python -m pytest -m "not slow" -n 2 --dist worksteal --durations=20

bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[bench]'
	$(BIN)/python benchmarks/run.py --quick

# Long experiments stay out of the default test run.
test-slow: $(STAMP)
	$(BIN)/python -m pytest -m slow

bench-all: $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[bench]'
	$(BIN)/python benchmarks/run.py --quick
	$(BIN)/python benchmarks/bench_engine.py --quick
	$(BIN)/python benchmarks/bench_rw_temperature.py --progpy
	$(BIN)/python benchmarks/bench_rw_degradation.py --workers 2
	$(BIN)/python benchmarks/bench_particle_core.py
	$(BIN)/python benchmarks/bench_rw_telemetry.py
	$(BIN)/python benchmarks/rw_step1_accuracy.py --seed 1
	$(BIN)/python benchmarks/bench_rw_mission.py
	$(BIN)/python benchmarks/bench_friction_rul.py
	$(BIN)/python benchmarks/bench_trackers.py
	$(BIN)/python benchmarks/bench_scale.py
	$(BIN)/python benchmarks/bench_export.py

# The four full reproductions (tens of minutes on 2 cores), each into out/<system>/.
reproduce: $(STAMP)
	$(BIN)/rulkit reproduce rw-lubrication --workers 2 --out out/rw-lubrication
	$(BIN)/rulkit reproduce motor-damping --out out/motor-damping
	$(BIN)/rulkit reproduce friction-drive --out out/friction-drive
	$(BIN)/rulkit reproduce embedded-rul --out out/embedded-rul

# The documentation site into site/ (open site/index.html): docs/ + the API from the docstrings.
# Installs the `docs` extra; the build itself needs no network (no CDN fonts).
docs: $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[docs]'
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

lint: $(STAMP)
	$(BIN)/ruff check .

clean:
	rm -rf $(VENV) demo-out out site build *.egg-info src/*.egg-info

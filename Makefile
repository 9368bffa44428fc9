# Two commands on a fresh machine: `make demo` and `make test`. Both create the virtualenv.
VENV ?= .venv
PY := $(VENV)/bin/python
BIN := $(VENV)/bin
DEMO ?= demo

.PHONY: setup test lint demo bench clean

setup: $(VENV)/.installed

# torch first, pinned: this is the local CPU build; an unpinned torch pulls a multi-GB CUDA build.
$(VENV)/.installed: pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[dev,samples]'
	touch $@

test: setup
	$(PY) -m pytest -q -n 2 --durations=10

lint: setup
	$(BIN)/ruff check projsynth projreg tests bench

demo: setup
	$(BIN)/projsynth gen --out $(DEMO)/train --pairs 1 --workers 2 --seed 1
	$(BIN)/projsynth verify $(DEMO)/train
	$(BIN)/projsynth inspect $(DEMO)/train
	$(BIN)/projsynth preview $(DEMO)/train --out $(DEMO)/preview.png --count 8
	@echo "demo: dataset in $(DEMO)/train, contact sheet in $(DEMO)/preview.png"

bench: setup
	$(PY) bench/bench_gen.py

clean:
	rm -rf $(VENV) $(DEMO) .pytest_cache .ruff_cache

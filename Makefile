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

# About 5 minutes on 2 cores: data, a short training run, and a benchmark table against baselines.
demo: setup
	$(BIN)/projsynth gen --out $(DEMO)/train --pairs 1 --workers 2 --seed 1
	$(BIN)/projsynth gen --out $(DEMO)/test --split test --pairs 1 --workers 2 --seed 1 \
		--transforms 0,9,22,31,44,53,66,75,88,97,110,119,132,141,154,158
	$(BIN)/projsynth verify $(DEMO)/train
	$(BIN)/projsynth inspect $(DEMO)/train
	$(BIN)/projsynth preview $(DEMO)/train --out $(DEMO)/preview.png --count 8
	$(BIN)/projreg train --data $(DEMO)/train --val $(DEMO)/test --out $(DEMO)/run --steps 60 --batch-size 2 \
		--crop 128x160 --val-every 60 --workers 2 $(if $(wildcard $(DEMO)/run/checkpoints/last.pt),--resume,)
	$(BIN)/projreg bench --data $(DEMO)/test --model $(DEMO)/run/checkpoints/last.pt --limit 16 \
		--json $(DEMO)/bench.json --markdown $(DEMO)/bench.md
	@echo "demo: data in $(DEMO)/, contact sheet $(DEMO)/preview.png, run $(DEMO)/run, table $(DEMO)/bench.md"

bench: setup
	$(PY) bench/bench_gen.py

clean:
	rm -rf $(VENV) $(DEMO) .pytest_cache .ruff_cache

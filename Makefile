# Two commands on a fresh machine: `make demo` and `make test`. Both create the virtualenv.
VENV ?= .venv
PY := $(VENV)/bin/python
BIN := $(VENV)/bin
DEMO ?= demo

.PHONY: device-wheels clean-kernels setup test lint demo bench reference-model test-bench real-bench hard-bench external-bench real-protocol bench-decode results results-all clean

setup: $(VENV)/.installed

# torch first, pinned: this is the local CPU build; an unpinned torch pulls a multi-GB CUDA build.
$(VENV)/.installed: pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[dev,samples,onnx]'
	touch $@

test: setup
	$(PY) -m pytest -q -n 2 --durations=10

lint: setup
	$(BIN)/ruff check projsynth projreg tests bench

# A tour: data at 192x256, a short training run, a small benchmark against the baselines; 5.7 CPU-min
# (about 3-6 min on 2 idle cores, README). One shell, so that the total time can be printed at the end.
DEMO_SPREAD := 0,9,22,31,44,53,66,75,88,97,110,119,132,141,154,158
demo: setup
	@start=$$(date +%s); set -ex; \
	$(BIN)/projsynth gen --out $(DEMO)/train --pairs 1 --size 192x256 --transforms $(SPREAD32) --workers 2 --seed 1; \
	$(BIN)/projsynth gen --out $(DEMO)/test --split test --pairs 1 --size 192x256 --transforms $(DEMO_SPREAD) \
		--workers 2 --seed 1; \
	$(BIN)/projsynth verify $(DEMO)/train; \
	$(BIN)/projsynth inspect $(DEMO)/train; \
	$(BIN)/projsynth preview $(DEMO)/train --out $(DEMO)/preview.png --count 6; \
	$(BIN)/projreg train --data $(DEMO)/train --val $(DEMO)/test --out $(DEMO)/run --steps 40 --batch-size 2 \
		--crop 128x160 --val-every 40 --val-samples 8 --workers 1 --no-activation-checkpointing \
		$(if $(wildcard $(DEMO)/run/checkpoints/last.pt),--resume,); \
	$(BIN)/projreg bench --data $(DEMO)/test --model $(DEMO)/run/checkpoints/last.pt --model reference --limit 8 \
		--json $(DEMO)/bench.json --markdown $(DEMO)/bench.md; \
	set +x; \
	echo "demo: data in $(DEMO)/, contact sheet $(DEMO)/preview.png, run $(DEMO)/run, table $(DEMO)/bench.md"; \
	echo "demo: done in $$(( ($$(date +%s) - start) / 60 )) min $$(( ($$(date +%s) - start) % 60 )) s"

bench: setup
	$(PY) bench/bench_gen.py

# Wheels the GPU machine lacks (its python3 3.12 has torch with CUDA and the rest): for bench/device_run.sh
device-wheels:
	python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
		--platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 -d .whl "OpenEXR==3.5.3"
	grep -qx '/.whl/' .git/info/exclude 2>/dev/null || echo /.whl/ >> .git/info/exclude

# The shipped reference model, from scratch (docs/model.md): built-in procedural images only, so every
# photograph stays unseen. About 4 h 20 min on 2 CPU cores and 27 GB of shards; re-running resumes the data
# and the training. Four stages: 2,200 steps of a 3,000-step schedule at 192 x 256 crops, then 800 steps from
# those weights (--init) at 256 x 320 crops with the learning rate decaying from where the first stage
# stopped, then 600 steps from those at 320 x 448 crops from lr 6e-5, then the same again with 24 more
# source pairs beside the 12 (docs/model.md, "Reference model").
REF ?= build/reference
reference-model: setup
	$(BIN)/projsynth gen --out $(REF)/train --split train --pairs 12 --seed 1 --workers 2 --quiet
	$(BIN)/projsynth gen --out $(REF)/val --split val --pairs 1 --seed 1 --workers 2 --quiet
	$(BIN)/projreg train --data $(REF)/train --val $(REF)/val --out $(REF)/run --model small --steps 2200 \
		--schedule-steps 3000 --warmup-steps 100 --batch-size 6 --crop 192x256 --val-every 500 --workers 1 \
		--no-activation-checkpointing --seed 0 --quiet $(if $(wildcard $(REF)/run/checkpoints/last.pt),--resume,)
	$(BIN)/projreg train --data $(REF)/train --val $(REF)/val --out $(REF)/finish --model small \
		--init $(REF)/run/checkpoints/last.pt --steps 800 --schedule-steps 800 --warmup-steps 20 --lr 1.1e-4 \
		--batch-size 6 --crop 256x320 --val-every 400 --workers 1 --no-activation-checkpointing --seed 1 --quiet \
		$(if $(wildcard $(REF)/finish/checkpoints/last.pt),--resume,)
	$(BIN)/projreg train --data $(REF)/train --val $(REF)/val --out $(REF)/stage3 --model small \
		--init $(REF)/finish/checkpoints/last.pt --steps 600 --schedule-steps 600 --warmup-steps 20 --lr 6e-5 \
		--batch-size 6 --crop 320x448 --val-every 300 --workers 1 --no-activation-checkpointing --seed 2 --quiet \
		$(if $(wildcard $(REF)/stage3/checkpoints/last.pt),--resume,)
	$(BIN)/projsynth gen --out $(REF)/train24s2 --split train --pairs 24 --seed 2 --workers 2 --quiet
	$(BIN)/projreg train --data $(REF)/train --data $(REF)/train24s2 --val $(REF)/val --out $(REF)/stage4 --model small \
		--init $(REF)/stage3/checkpoints/last.pt --steps 600 --schedule-steps 600 --warmup-steps 20 --lr 6e-5 \
		--batch-size 6 --crop 320x448 --val-every 300 --workers 1 --no-activation-checkpointing --seed 3 --quiet \
		$(if $(wildcard $(REF)/stage4/checkpoints/last.pt),--resume,)
	$(BIN)/projreg export --checkpoint $(REF)/stage4/checkpoints/last.pt --out projreg/weights/reference.pt

BASELINES := dis-fast,dis-medium,farneback,sift-ransac
# 32 transforms: every (family, severity) once, photometric conditions in rotation
SPREAD32 := 0,6,12,18,21,27,33,39,42,48,54,55,63,69,70,76,84,85,91,97,100,106,112,118,121,127,133,139,142,148,154,155

# The reference model against the baselines on a fresh synthetic test split (all 160 transforms)
test-bench: setup
	$(BIN)/projsynth gen --out build/test-split --split test --pairs 1 --seed 123 --workers 2 --quiet
	$(BIN)/projreg bench --data build/test-split --baselines $(BASELINES) --refine both --json build/test-bench.json \
		--markdown build/test-bench.md --quiet

# ... and on real pictures it never saw: scikit-image's photographs x its artwork (bench/real_sources.py)
real-bench: setup
	$(PY) bench/real_sources.py --out build/real
	$(BIN)/projsynth gen --out build/real-test --natural build/real/natural --generated build/real/generated \
		--split all --seed 5 --transforms $(SPREAD32) --workers 2 --quiet
	$(BIN)/projreg bench --data build/real-test --baselines $(BASELINES) --refine both --json build/real-bench.json \
		--markdown build/real-bench.md --quiet

# ... and on adversarial pictures (bench/hard_sources.py): content on part of the frame, near-uniform,
# repetitive and striped content, rendered with the physical model (non-linear response, daylight)
hard-bench: setup
	$(PY) bench/hard_sources.py --out build/hard
	$(BIN)/projsynth gen --out build/hard-test --natural build/hard/natural --generated build/hard/generated \
		--split all --seed 11 --blend physical --transforms $(SPREAD32) --workers 2 --quiet
	$(BIN)/projreg bench --data build/hard-test --baselines $(BASELINES) --refine both --limit 48 \
		--json build/hard-bench.json --markdown build/hard-bench.md --quiet

# ... and issue 16's check on pairs rendered by a rig written from scratch in bench/external_rig.py (not projsynth):
# `projreg predict` per pair against SIFT + RANSAC and DIS medium; the second run is a bent sheet with painted stripes
external-bench: setup
	$(PY) bench/external_rig.py --out build/external --json build/external.json --markdown build/external.md
	$(PY) bench/external_rig.py --out build/external-stripes --shape bend --albedo stripes --response gamma --ambient 0 \
		--json build/external-stripes.json --markdown build/external-stripes.md

# The paper's real-world protocol (Table 4) on the virtual rig: a concave surface with a heart-like textured
# interference and a convex one with a brightened centre; 11 dot patterns -> 400-point truth; the bench on
# the decoded dots beside the same bench on the exact dense truth (docs/real-rig.md). About 10 min on 2 cores.
RP := build/real-protocol
real-protocol: setup
	$(PY) bench/real_protocol.py prepare --out $(RP)
	for s in concave convex; do for gt in dots exact; do \
		$(BIN)/projreg bench --data $(RP)/$$s-$$gt --baselines $(BASELINES) --refine both --json $(RP)/$$s-$$gt.json \
			--quiet > /dev/null || exit 1; done; done
	$(PY) bench/real_protocol.py table $(RP) | tee $(RP)/table.md

# Structured-light decode accuracy on the virtual rig, every 4th transform (docs/results.md)
bench-decode: setup
	$(PY) bench/bench_decode.py

# docs/results.md, the current figures, from the stored measurements under docs/results/ alone
# (bench/results_page.py): nothing is measured, and without new measurements no byte changes
# (tests/test_results_page.py checks the committed page).
results: setup
	$(PY) bench/results_page.py

# Re-measure one evaluation set at the checked-out commit, then rewrite the page: bench/record.py SET runs the
# set's commands at their stated sizes on one core (about 15 min at most each; data under build/results/) and
# stores its reports and metadata in docs/results/. SET: synthetic, real, hard, decode, compensation, tracking,
# external, or latency (on an idle machine only: the one set whose timings the page shows; THREADS=N to give it N
# cores, e.g. `make results-latency THREADS=2`). results-all: every set but latency, about an hour on one core.
THREADS ?= 1
results-all: setup
	$(PY) bench/record.py --all --threads $(THREADS)
	$(PY) bench/results_page.py

results-%: setup
	$(PY) bench/record.py $* --threads $(THREADS)
	$(PY) bench/results_page.py

clean:
	rm -rf $(VENV) $(DEMO) build .pytest_cache .ruff_cache
	find projsynth projreg \( -name '*.nbi' -o -name '*.nbc' \) -delete

# numba's cache is keyed on each kernel's own file: after editing a helper in another module
# (e.g. surface.py, inlined into scene.py's kernels) drop the compiled kernels with this.
clean-kernels:
	find projsynth projreg \( -name '*.nbi' -o -name '*.nbc' \) -delete

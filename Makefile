# Two commands do everything on a fresh machine:
#   make run    set up and run the main job (the separation paper's three-method comparison)
#   make test   set up and run the whole test suite (what CI runs)
SHELL := /bin/bash
# The interpreter the environment is built on: the distribution's own python3 where it is 3.11 (every committed run's
# Python) and can make a venv (Debian builds it with profile-guided and link-time optimisation: a few per cent less
# CPU than a plain source build of 3.11, the same bits out: studies/environment/README.md), else the first python3 on
# PATH; `make test PYTHON=python3` chooses another. The venv is synced again when the interpreter changes.
ifeq ($(origin PYTHON),undefined)
PYTHON := $(or $(shell for p in /usr/bin/python3 python3; do $$p -c 'import sys, ensurepip, venv; sys.exit(sys.version_info[:2] != (3, 11))' >/dev/null 2>&1 && { command -v $$p; break; }; done),python3)
endif
VENV := .venv
PY := $(VENV)/bin/python
# uv installs exactly what uv.lock pins (every extra: test, peers, dask) into .venv; uv itself comes pinned by
# hash from .ci/uv-requirements.txt into .tools/. `make lock` is the only target that changes uv.lock.
TOOLS := .tools
UV := $(TOOLS)/bin/uv
# Bytecode: every target below writes the .pyc of what it imports, once (PYTHONDONTWRITEBYTECODE cleared for them:
# where an environment sets it, each process would compile scipy, matplotlib, rerun and the project's own modules
# again at its start, ~3 s of CPU for a campaign's worker); only what is imported is compiled, not the 12685 files
# of every installed package (~21 s of the install on two cores)
export PYTHONDONTWRITEBYTECODE :=
SYNC_FLAGS := --frozen --all-extras
STAMP := $(VENV)/.synced-$(shell (cat pyproject.toml uv.lock; echo '$(SYNC_FLAGS)'; readlink -f "$$(command -v $(PYTHON))") | sha1sum | cut -c1-12)
export UV_PYTHON_DOWNLOADS := never
export MUJOCO_GL ?= egl
# many small linear-algebra problems: threaded BLAS only thrashes on 2 shared cores (see twin/runtime.py)
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1
# one BLAS kernel on every x86-64 machine: OpenBLAS picks its kernels by CPU (an AVX-512 machine's differ from an
# AVX2 one's in the last bits), and the golden regression test asks for bit-identical 6R results
export OPENBLAS_CORETYPE ?= Haswell
# numpy's own kernels (sin, cos, exp... dispatched by CPU) pinned to the AVX2 level for the same reason: an AVX-512
# machine's differ from an AVX2 one's in the last bits; disabling a feature a machine lacks changes nothing
export NPY_DISABLE_CPU_FEATURES ?= X86_V4 AVX512_ICL AVX512_SPR
# test workers: one per core (pytest-xdist)
JOBS ?= $(shell nproc 2>/dev/null || echo 2)

.PHONY: run run-quick test test-fast bench results install lock sysdeps sysdeps-browser clean

$(UV): .ci/uv-requirements.txt
	$(PYTHON) -m venv $(TOOLS)
	$(TOOLS)/bin/python -m pip install -q --require-hashes -r .ci/uv-requirements.txt
	touch $(UV)

$(STAMP): pyproject.toml uv.lock | $(UV)
	$(UV) sync $(SYNC_FLAGS) --python $(PYTHON)
	rm -f $(VENV)/.synced-*
	touch $(STAMP)

install: sysdeps $(STAMP)

# Refresh the lock deliberately (newest releases allowed by pyproject.toml), then rerun the suite and the
# benchmarks before committing uv.lock with what they measured.
lock: $(UV)
	$(UV) lock --upgrade
	@echo "uv.lock refreshed: now run make test and make bench, and commit uv.lock with their results"

# Offscreen MuJoCo rendering needs Mesa's EGL (llvmpipe on CPU).
sysdeps:
	@if ! ldconfig -p | grep -q 'libEGL.so.1' || ! ls /usr/lib/*/dri/swrast_dri.so >/dev/null 2>&1; then \
	  echo "installing Mesa EGL (apt-get)"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libegl1 libegl-mesa0 libgl1-mesa-dri libgl1 >/dev/null; \
	fi

# The recording test opens the Rerun web viewer in headless Chromium.
sysdeps-browser:
	@if ! command -v chromium >/dev/null || ! command -v chromedriver >/dev/null; then \
	  echo "installing chromium + chromium-driver (apt-get)"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver >/dev/null; \
	fi

run: install
	$(VENV)/bin/twin campaign experiments/separation.toml --out results/separation

run-quick: install
	$(VENV)/bin/twin campaign experiments/separation.toml --out results/separation-quick --quick

# the whole suite, the peer-adapter tests included (they skip, with the reason, only where a peer is missing)
test: install sysdeps-browser
	$(PY) -m pytest -q -n $(JOBS) --dist worksteal

test-fast: install
	$(PY) -m pytest -q -n $(JOBS) --dist worksteal -m "not slow and not browser"

bench: install
	$(PY) experiments/benchmark.py

# Every figure made by `twin diagnose`, run again after a change to what the diagnosis computes (studies/README.md,
# "When the diagnosis changes"): about three hours on two cores; then the README rows that quote them
# (tests/test_readme_figures.py names the passages that moved).
DRAWN_SETS := 100-119:results_fresh 200-219:results_held 300-319:results_300 400-419:results_400 \
	500-519:results_500 600-619:results_600 700-719:results_700 800-819:results_800 \
	900-919:results_900 1000-1019:results_1000 1100-1119:results_1100
results: install
	$(PY) experiments/bench_drawn_effects.py --draws 20 --workers 2
	for s in $(DRAWN_SETS); do \
	  $(PY) -m studies.drawn.run --seeds $${s%%:*} --workers 2 --out studies/drawn/$${s##*:} || exit 1; \
	done
	$(PY) -m studies.drawn.run --families mixed --seeds 0-199 --workers 2 --out studies/drawn/results_mixed
	$(PY) studies/blind/run.py --workers 2 --only a b c d e f
	$(PY) studies/close_loop/close_loop.py studies/close_loop/close_loop.toml --out studies/close_loop/results/close_loop
	$(PY) studies/close_loop/close_loop.py studies/close_loop/close_loop_clean.toml --out studies/close_loop/results/close_loop_clean
	$(PY) studies/close_loop/sensitivity.py
	$(PY) studies/tiago_mocap/run.py
	$(PY) studies/ur5_laser_tracker/run.py
	$(PY) studies/ur10_laser_tracker/run.py
	$(PY) studies/ur10_laser_tracker/transfer.py
	$(PY) -m studies.mixture.run --seeds 1000-1029 --workers 2
	$(PY) experiments/bench_newcomer.py --cases 400 --corrupted 400 --workers 2
	$(PY) experiments/bench_diagnosis_rates.py --jobs 2
	$(PY) experiments/bench_diagnosis.py
	$(PY) experiments/bench_diagnosis_scale.py
	$(PY) experiments/bench_configurations.py
	$(PY) experiments/bench_suite.py --runs 1 --reference fa0dd40

clean:
	rm -rf $(VENV) $(TOOLS) .pytest_cache

# Two commands do everything on a fresh machine:
#   make run    set up and run the main job (the separation paper's three-method comparison)
#   make test   set up and run the whole test suite (what CI runs)
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-$(shell cat pyproject.toml | sha1sum | cut -c1-12)
PEERS_STAMP := $(VENV)/.peers-$(shell cat pyproject.toml | sha1sum | cut -c1-12)
export MUJOCO_GL ?= egl
# many small linear-algebra problems: threaded BLAS only thrashes on 2 shared cores (see twin/__init__.py)
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1

.PHONY: run run-quick test test-fast bench install peers sysdeps sysdeps-browser clean

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install -q -e ".[test]"
	rm -f $(VENV)/.installed-*
	touch $(STAMP)

install: sysdeps $(STAMP)

# The peer calibrators (FIGAROH with Pinocchio, pybotics, robotkinecal): the adapter tests of `make test` and
# `make bench` need them. pybotics and robotkinecal pin numpy<2 in their metadata (rerun-sdk needs numpy>=2);
# they run on numpy 2, so they are installed without their metadata's dependencies, which the `peers` extra
# brings instead (pyproject.toml).
$(PEERS_STAMP): $(STAMP)
	$(PY) -m pip install -q -e ".[test,peers]"
	$(PY) -m pip install -q --no-deps "pybotics>=3.1.2,<4" "robotkinecal>=0.1.0,<0.2"
	rm -f $(VENV)/.peers-*
	touch $(PEERS_STAMP)

peers: install $(PEERS_STAMP)

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
test: install peers sysdeps-browser
	$(PY) -m pytest -q

test-fast: install
	$(PY) -m pytest -q -m "not slow and not browser"

bench: peers
	$(PY) experiments/benchmark.py

clean:
	rm -rf $(VENV) .pytest_cache

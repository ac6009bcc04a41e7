# Every target that runs our code depends on .venv (make setup), which installs from nothing.
SHELL := /bin/bash
PY ?= python3
VENV := .venv
PYTHON := $(VENV)/bin/python
# Shared libraries bpy loads even headless.
APT_LIBS := libx11-6 libxrender1 libxfixes3 libxi6 libxkbcommon0 libsm6 libice6 libgl1 libegl1 \
            libxxf86vm1 libxext6 libxcursor1 libxinerama1 libxrandr2 libglu1-mesa

# Headless browser for the report's test (tests/test_report.py).
BROWSER_PKGS := chromium chromium-driver

.PHONY: setup browser test bench demo dataset train eval ablation clean

setup: $(VENV)/.done

$(VENV)/.done: requirements.txt pyproject.toml setup.py Makefile
	@missing=""; for p in $(APT_LIBS); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing shared libraries for bpy:$$missing"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; \
	fi
	@test -x $(PYTHON) || $(PY) -m venv $(VENV)
	$(PYTHON) -m pip install -q -r requirements.txt
	@# the project itself, editable (console commands fisheye-bev-dataset/-train/-eval); offline: the build
	@# uses the venv's setuptools, the dependencies are the lines above
	$(PYTHON) -m pip install -q "setuptools>=64"
	$(PYTHON) -m pip install -q --no-build-isolation --no-deps -e .
	$(PYTHON) -c "import bpy, torch, OpenEXR, kornia, cv2, ray; print('setup ok: bpy', bpy.app.version_string, 'torch', torch.__version__)"
	@touch $@

browser:
	@missing=""; for p in $(BROWSER_PKGS); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing the headless browser for the report test:$$missing"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; \
	fi

# Options: make dataset PRESET=medium DATA=data/medium WORKERS=2 BACKEND=ray (cluster: RAY_ADDRESS); make train CONFIG=... MINUTES=30 (train.minutes); make eval SPLIT=hard
PRESET ?= medium
DATA ?= data/$(PRESET)
CONFIG ?= configs/train/cpu_medium.yaml
RUN ?= runs/$(basename $(notdir $(CONFIG)))
SPLIT ?= all
WORKERS ?=
BACKEND ?= local

test: setup browser
	$(PYTHON) -m pytest -q tests

bench: setup
	$(PYTHON) -m bench.run

dataset: setup
	$(PYTHON) -m dataset_tools dataset --config configs/dataset/$(PRESET).yaml --out $(DATA) --backend $(BACKEND) $(if $(WORKERS),--workers $(WORKERS)) $(if $(RERENDER),--rerender-changed)

train: setup
	$(PYTHON) train.py --config $(CONFIG) --out $(RUN) $(if $(MINUTES),--set train.minutes=$(MINUTES))

eval: setup
	$(PYTHON) eval.py --checkpoint $(RUN) --split $(SPLIT)

# make ablation [STEPS=420] [SEEDS=1] [SEEDS2=$(SEEDS)] [SCALE=cpu] [DATA=data/medium] [OUT=runs/ablation] [JOBS=1]: the
# paper's Tables I and II with intervals and verdicts; every row the same optimiser steps (BUDGET=minutes: the same wall
# clock instead); SEEDS for Table I's rows, SEEDS2 for the other rows; JOBS rows train at once (cores/JOBS threads each)
STEPS ?= 420
BUDGET ?=
SEEDS ?= 1
SEEDS2 ?= $(SEEDS)
SCALE ?= cpu
OUT ?= runs/ablation
JOBS ?= 1
ablation: setup
	$(PYTHON) -m experiments.ablation $(if $(BUDGET),--budget-minutes $(BUDGET),--steps $(STEPS)) --seeds $(SEEDS) --seeds-table2 $(SEEDS2) --scale $(SCALE) --out $(OUT) --jobs $(JOBS) $(if $(filter command line,$(origin DATA)),--data $(DATA))

demo: setup
	$(PYTHON) demo.py

clean:
	rm -rf $(VENV)

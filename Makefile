# Everything a fresh Debian machine with Python 3.11 needs: `make demo`, `make test`.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
# The ROS 2 wheels install share/<pkg> under the venv; ament_index_python finds them here.
export AMENT_PREFIX_PATH := $(abspath $(VENV))
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export NUMBA_CACHE_DIR := $(abspath $(VENV))/numba-cache

.PHONY: venv demo test lint bench clean

venv: $(STAMP)

$(STAMP): requirements.txt setup.py
	@command -v $(PYTHON) >/dev/null || { echo "need $(PYTHON) (Debian: apt-get install python3 python3-venv)"; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.txt
	$(PY) -m pip install --quiet --no-deps -e .
	$(PY) -m cvt_ros warmup
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m cvt_ros demo

test: $(STAMP)
	$(PY) -m pytest -q test

lint: $(STAMP)
	$(VENV)/bin/ruff check cvt_ros test

bench: $(STAMP)
	$(PY) -m cvt_ros bench

clean:
	rm -rf $(VENV) build install log

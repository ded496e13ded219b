# Two entry points (README): `make demo` runs the main job, `make test` runs the test suite.
# Both create the virtual environment .venv inside the repository on first use.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
ROSENV := ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
OUT ?= out/demo

.PHONY: demo test lint bench clean

$(VENV)/.installed: setup.py setup.cfg package.xml pyproject.toml
	$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' || { echo "Python 3.11 or newer is needed (PYTHON=$(PYTHON))"; exit 1; }
	$(PYTHON) -m venv $(VENV) || { echo "python3 -m venv failed: install python3-venv (apt-get install python3-venv)"; exit 1; }
	$(PY) -m pip install -q --upgrade pip 'setuptools<80' wheel
	$(PY) -m pip install -q -e '.[ros,test]'
	touch $@

demo: $(VENV)/.installed
	$(ROSENV) $(VENV)/bin/railgsa demo --out $(OUT)

test: $(VENV)/.installed
	$(ROSENV) $(PY) -m pytest -q -p no:cacheprovider --durations=30

lint: $(VENV)/.installed
	$(VENV)/bin/ruff check .

bench: $(VENV)/.installed
	$(VENV)/bin/pip install -q -e '.[ros,test,bench]'
	for b in benchmarks/bench_*.py; do $(ROSENV) $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) out build *.egg-info

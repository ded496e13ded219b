# Two entry points (README): `make demo` runs the main job, `make test` runs the test suite.
# Both create the virtual environment .venv inside the repository on first use and install into
# it what they use (setup.py's extras): the demo ros,review,fleet; the tests those and dev.
# Each step prints a line, and pip shows its downloads and installs (no silent minutes).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip install --progress-bar on
ROSENV := ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
OUT ?= out/demo
DEPS := setup.py setup.cfg package.xml pyproject.toml
DEMO_EXTRAS := ros,review,fleet
TEST_EXTRAS := $(DEMO_EXTRAS),dev

.PHONY: demo test lint bench clean

$(VENV)/.created:
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' || { echo "Python 3.11 or newer is needed (PYTHON=$(PYTHON))"; exit 1; }
	@echo '==> set-up 1/3: creating the virtual environment $(VENV)'
	$(PYTHON) -m venv $(VENV) || { echo "python3 -m venv failed: install python3-venv (apt-get install python3-venv)"; exit 1; }
	@echo '==> set-up 2/3: upgrading pip, setuptools, wheel'
	$(PIP) --upgrade pip 'setuptools<80' wheel
	touch $@

$(VENV)/.installed-demo: $(DEPS) $(VENV)/.created
	@echo '==> set-up 3/3: installing railgsa_ros[$(DEMO_EXTRAS)] (a few minutes the first time)'
	$(PIP) -e '.[$(DEMO_EXTRAS)]'
	@echo '==> set-up done'
	touch $@

$(VENV)/.installed-test: $(DEPS) $(VENV)/.created
	@echo '==> set-up 3/3: installing railgsa_ros[$(TEST_EXTRAS)] (a few minutes the first time)'
	$(PIP) -e '.[$(TEST_EXTRAS)]'
	@echo '==> set-up done'
	touch $@ $(VENV)/.installed-demo

demo: $(VENV)/.installed-demo
	$(ROSENV) $(VENV)/bin/railgsa demo --out $(OUT)

test: $(VENV)/.installed-test
	$(ROSENV) $(PY) -m pytest -q -p no:cacheprovider --durations=30

lint: $(VENV)/.installed-test
	$(VENV)/bin/ruff check .

bench: $(VENV)/.installed-test
	$(PIP) -e '.[$(TEST_EXTRAS),bench]'
	for b in benchmarks/bench_*.py; do $(ROSENV) $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) out build *.egg-info

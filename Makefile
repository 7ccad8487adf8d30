# One-command set-up: every target below creates or refreshes the venv from the
# pinned requirements first. With a sourced ROS 2 (rclpy importable) the venv
# sees the system packages and the ROS 2 wheels are not installed. setup.cfg puts the
# executables in lib/qfa_ros (where `ros2 run` looks); they are linked into the venv's bin.
#
# ROS_DISTRO chooses the wheel set: kilted (default; .venv, requirements/ros.txt and
# base.txt) or jazzy, the LTS (.venv-jazzy, ros-jazzy.txt and the library floor
# floor.txt: Ubuntu 24.04's numpy, scipy and numba), e.g. `make test ROS_DISTRO=jazzy`.
# A sourced ROS 2 sets ROS_DISTRO itself: jazzy's venv then takes the floor with the
# system rclpy, any other distribution .venv. Both venvs can exist side by side; each
# keeps numba's cache of this tree in its own directory (the two numba versions would
# overwrite each other's index in __pycache__).
PYTHON ?= python3
ROS_DISTRO ?= kilted
ifeq ($(ROS_DISTRO),jazzy)
VENV := .venv-jazzy
ROS_WHEELS := requirements/ros-jazzy.txt
LIBRARIES := requirements/floor.txt
TOOLS := requirements/tools-floor.txt
NUMBA_CACHE := $(CURDIR)/.venv-jazzy/numba_cache
else
VENV := .venv
ROS_WHEELS := requirements/ros.txt
LIBRARIES := requirements/base.txt
TOOLS := requirements/tools.txt
NUMBA_CACHE :=
endif
PY := $(VENV)/bin/python
PIP := $(PY) -m pip install -q --disable-pip-version-check
# The pinned requirements go in through uv (pip-installed into the venv first): the same
# packages as pip's, set up in 29 s against pip's 110 s (the four files, one venv:
# bench/results/suite_time.md). Where uv cannot be installed or fails, pip does it. uv is
# installed once, by the node's set-up; `make setup` finds it.
UV := uv==0.13.8
INSTALL := install() { { { [ -x $(VENV)/bin/uv ] || $(PIP) $(UV); } && $(VENV)/bin/uv pip \
  install -q --python $(PY) --compile-bytecode "$$@"; } || $(PIP) "$$@"; }; install
STAMP := $(VENV)/.qfa-installed
NODE_STAMP := $(VENV)/.qfa-node
DURATION ?= 10
# More pytest arguments for `make test`, e.g. TESTS='test/test_node_stream.py -x'.
TESTS ?=

.PHONY: setup run sim test lint docs bench reproducibility bags figures clean

BAGS := bags/static_10s.mcap bags/paper_2019.mcap bags/temperature_cycle.mcap

setup: $(STAMP)

# What the node and qfa-sim need (base.txt or floor.txt, the ROS 2 wheels unless rclpy is
# on the system) and the package itself: all `make run` and `make sim` install.
$(NODE_STAMP): $(ROS_WHEELS) $(LIBRARIES) setup.py
	@if $(PYTHON) -c 'import rclpy' >/dev/null 2>&1; then \
	  echo 'rclpy found on the system: using it, not the ROS 2 wheels'; \
	  $(PYTHON) -m venv --system-site-packages $(VENV); ros=''; \
	else \
	  $(PYTHON) -m venv $(VENV); ros='-r $(ROS_WHEELS)'; \
	fi; \
	if [ -n '$(NUMBA_CACHE)' ]; then \
	  site=$$($(PY) -c 'import sysconfig; print(sysconfig.get_path("purelib"))'); \
	  line="import os; os.environ.setdefault('NUMBA_CACHE_DIR', '$(NUMBA_CACHE)')"; \
	  [ -d "$$site" ] && echo "$$line" > "$$site/qfa_numba_cache.pth"; \
	fi; \
	$(INSTALL) -r $(LIBRARIES) $$ros && \
	$(PIP) --no-deps --no-build-isolation -e . && \
	$(PY) -m compileall -q qfa_ros && \
	$(PY) -m qfa_ros.cli.warm_cache && \
	for script in $(VENV)/lib/qfa_ros/*; do [ -e "$$script" ] && ln -sf "../lib/qfa_ros/$${script##*/}" $(VENV)/bin/; done; \
	touch $@

# Everything: the fleet and figure tools, the test and documentation tools besides; and the
# suite's trajectory kernels into numba's cache (23 CPU-s on a fresh clone, which the first
# test session would otherwise spend at its start while its workers wait).
$(STAMP): $(NODE_STAMP) $(TOOLS) requirements/test.txt
	@$(INSTALL) -r $(TOOLS) -r requirements/test.txt
	@$(PY) test/kernel_warmup.py trajectory $(VENV)/.qfa-kernels
	@touch $@

# The emulated sensor on DDS until Ctrl-C (the node finds config/fastdds_discovery.xml).
# More ROS arguments: make run ARGS='-p state.fresh:=true'. The module, not the qfa_node
# console script (the same main), which first looks its entry point up in the metadata.
run: $(NODE_STAMP)
	$(PY) -m qfa_ros.cli.node --ros-args --params-file config/qfa.yaml $(ARGS)

# The offline simulator, no DDS: a static run summarized with its Allan deviation.
sim: $(NODE_STAMP)
	$(VENV)/bin/qfa-sim static --duration $(DURATION)

# pytest keeps the test modules it rewrote for its assertions in __pycache__, unless the
# environment forbids writing bytecode: then every worker rewrites all of them on every run
# (~3 s of its collection), and the Jazzy run after the Kilted one (the same pytest) too.
test: $(STAMP)
	PYTHONDONTWRITEBYTECODE= $(PY) -m pytest $(TESTS)

lint: $(STAMP)
	$(VENV)/bin/ruff check .

# The documentation site (Sphinx, MyST Markdown, API from the docstrings); warnings are errors.
docs: $(STAMP)
	$(PY) -m sphinx -W --keep-going -b html docs docs/_build/html
	@echo 'open docs/_build/html/index.html'

bench: $(STAMP)
	$(PY) bench/loop_throughput.py
	$(PY) bench/sim_limit.py

# The reproducibility contract's tolerances, measured (docs/reproducibility.md; ~6 min).
reproducibility: $(STAMP)
	$(PY) bench/reproducibility.py

# Example bags, deterministic for the seeds given here (see bags/README.md).
bags: $(NODE_STAMP)
	rm -f $(BAGS)
	$(VENV)/bin/qfa-sim static --duration 10 --seed 1 --out bags/static_10s.mcap
	$(VENV)/bin/qfa-sim paper-2019 --seed 0 --out bags/paper_2019.mcap
	$(VENV)/bin/qfa-sim temperature-cycle --duration 3600 --seed 0 \
	  --out bags/temperature_cycle.mcap

# The docs' figures, drawn from the example bags.
figures: $(STAMP)
	$(VENV)/bin/qfa-report bags/paper_2019.mcap --out docs/figures
	$(VENV)/bin/qfa-report bags/temperature_cycle.mcap --out docs/figures

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache docs/_build

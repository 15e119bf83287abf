# One-stop set-up for a fresh machine with Python 3.11+ and no ROS installed.
#   make demo   create .venv if needed, then run the demo drive
#   make test   create .venv if needed, then run the whole test suite
# Dependencies are installed once, when the files that pin them change; the package itself is
# reinstalled (seconds, --no-deps) only when its sources change. A second run reinstalls nothing.
# The package is installed as a regular wheel, not editable: only then do its data files (the
# lib/planar_vo executables and the ament index entry that `ros2 run` needs) land in the venv.

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
DEPS   := $(VENV)/.deps-installed
STAMP  := $(VENV)/.planar_vo-installed
PIP    := $(PY) -m pip install --quiet --disable-pip-version-check
SOURCES := $(shell find planar_vo resource config -type f -not -name '*.pyc')

# Exact versions for a reproducible environment (setup.py carries the compatible ranges).
# Test-only tools: pytest, pytest-timeout, and evo (GPL; the tests run its evo_ape/evo_traj
# executables to cross-check planar_vo.evaluation; the package never imports it).
# poselib (the 'bench' extra) is here so that the benchmark tests run, not skip; Ray (the
# 'fleet' extra) so that the fleet tests run (quoted: [] is a shell glob).
PINS := \
	setuptools==80.9.0 \
	ros-jazzy-rclpy==7.1.6 \
	ros-jazzy-common-interfaces==5.3.6 \
	ros-jazzy-rmw-fastrtps-cpp==8.4.3 \
	numpy==2.4.6 \
	opencv-python-headless==4.13.0.92 \
	rosbags==0.11.9 \
	PyYAML==6.0.3 \
	tqdm==4.70.1 \
	threadpoolctl==3.8.0 \
	matplotlib==3.10.8 \
	pytest==9.0.3 \
	pytest-timeout==2.4.0 \
	evo==1.38.1 \
	poselib==2.0.5 \
	'ray[client]==2.60.0'

.PHONY: demo test venv clean

demo: $(STAMP)
	$(VENV)/bin/planar_vo demo $(ARGS)

test: $(STAMP)
	$(PY) -m pytest $(ARGS)

venv: $(STAMP)

$(DEPS): Makefile
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "planar_vo needs Python 3.11+, found " + sys.version.split()[0])'
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP) $(PINS)
	@touch $@

$(STAMP): $(DEPS) setup.py setup.cfg package.xml README.md $(SOURCES)
	$(PIP) --no-deps --no-build-isolation --force-reinstall .
	@rm -rf build
	@touch $@

clean:
	rm -rf $(VENV) build *.egg-info

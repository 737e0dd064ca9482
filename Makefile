# The two commands a newcomer needs: `make demo` and `make test`. Both build .venv first.
SHELL := /bin/bash
VENV ?= .venv
# The interpreter the venv is made from (3.10-3.12): make VENV=.venv312 PYTHON=python3.12 demo
PYTHON ?= python3
PY := $(VENV)/bin/python
STAMP := $(VENV)/.diffdrive_odom-installed
# ROS 2 launch + launch_ros (not on PyPI) where CI keeps them beside the clone; a clone
# without them skips the launch tests that need them (test/system/test_launch.py says why).
SHARED_LAUNCH ?= ../shared/launch
LAUNCH_STAMP := $(VENV)/.launch-installed
PIP_QUIET := 2>&1 | grep -v '^WARNING: Location' || true
# pip byte-compiles what it installs (its default; note that PIP_NO_COMPILE=1 does not turn
# that off: pip reads it as compile=1). Where PYTHONDONTWRITEBYTECODE is set, Python never
# writes those caches itself, and every process would compile the libraries it imports.

.PHONY: venv demo demo-docs test test-fast test-dds lint docs check bench clean

venv: $(STAMP) $(if $(wildcard $(SHARED_LAUNCH)/install.sh),$(LAUNCH_STAMP))

$(STAMP): requirements.txt setup.py setup.cfg package.xml scripts/build_tf2_msgs.sh
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip $(PIP_QUIET)
	set -o pipefail; $(PY) -m pip install -q -r requirements.txt 2>&1 | { grep -v '^WARNING: Location' || true; }
	bash scripts/build_tf2_msgs.sh $(VENV)
	set -o pipefail; $(PY) -m pip install -q --no-deps --no-build-isolation -e . 2>&1 | { grep -v '^WARNING: Location' || true; }
	$(PY) -c 'import rclpy, tf2_msgs.msg, nav_msgs.msg, rosbags, diffdrive_odom'
	touch $(STAMP)

$(LAUNCH_STAMP): $(STAMP) $(SHARED_LAUNCH)/install.sh
	bash $(SHARED_LAUNCH)/install.sh $(VENV)
	touch $(LAUNCH_STAMP)

# DEMO_ARGS: the demo's options, e.g. DEMO_ARGS="--short --output /tmp/demo" (CI on 3.12).
demo: venv
	$(VENV)/bin/diffdrive-odom demo $(DEMO_ARGS)

# The demo's table in README.md and doc/tools/demo.md and doc/images/trajectory.png,
# written from a run (lockstep: every run of one install prints the same table).
demo-docs: venv
	$(PY) scripts/demo_docs.py $(DEMO_ARGS)

# Tiers (markers in setup.cfg): test = everything (CI): all but the `serial` tests on four
# xdist workers (each its own DDS domain; on two cores, as the DDS tests mostly wait: 5.6
# min against 7.2 on two), then the `serial` ones on two (the CPU-heavy ones, xdist_group
# serial-heavy, one after another beside the waiting ones), then the `alone` one by itself;
# test-fast = the pure tier (no DDS, no child process, nothing slow), under a minute;
# test-dds = what talks over DDS.
# make test writes Python's bytecode caches (__pycache__, git-ignored) even where
# PYTHONDONTWRITEBYTECODE is set: without them each pytest process rewrote the 215 test
# modules again (4 s of CPU each) and each node the suite starts compiled the package again.
BYTECODE := env -u PYTHONDONTWRITEBYTECODE
test: venv
	rc=0; $(BYTECODE) $(PY) -m pytest -q -n 4 --dist loadgroup -m "not serial" || rc=$$?; \
	$(BYTECODE) $(PY) -m pytest -q -n 2 --dist loadgroup -m "serial and not alone" || rc=$$?; \
	$(BYTECODE) $(PY) -m pytest -q -m alone || rc=$$?; exit $$rc

test-fast: venv
	$(PY) -m pytest -q -m "not dds and not process and not slow"

test-dds: venv
	$(PY) -m pytest -q -m dds

lint: venv
	$(VENV)/bin/ruff check diffdrive_odom test bench scripts launch doc/_ext doc/conf.py
	$(VENV)/bin/mypy
	$(VENV)/bin/lint-imports

# The HTML documentation (doc/, as rosdoc2 builds it for docs.ros.org) into build/docs/html.
# -W: any warning fails, -n: every reference must resolve (with MyST's heading anchors,
# every internal link); -E: read every page again (no stale state), so it checks every page.
DOCS_OUT ?= build/docs
docs: venv
	$(VENV)/bin/sphinx-build -W --keep-going -n -E -q -b html doc $(DOCS_OUT)/html

check: test lint docs

bench: venv
	set -e; for f in bench/bench_*.py; do echo "== $$f"; $(PY) $$f; done

clean:
	rm -rf $(VENV) build install log demo_output .pytest_cache .mypy_cache .ruff_cache

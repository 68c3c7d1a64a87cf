# Two commands set everything up on a fresh machine: `make demo` and `make test`.
# The interpreter of the venv: the first of python3.12 (Ubuntu 24.04, ROS 2 Jazzy's own),
# python3.11 and python3 that runs and is 3.11 or 3.12 (the versions the ROS Jazzy wheels of
# requirements.txt exist for). Another one: `make test PYTHON=/path/to/python3.12`.
SUPPORTED_PYTHON := import sys; sys.exit(not (3, 11) <= sys.version_info[:2] <= (3, 12))
ifndef PYTHON
PYTHON := $(firstword $(foreach p,python3.12 python3.11 python3,\
	$(shell $(p) -c '$(SUPPORTED_PYTHON)' >/dev/null 2>&1 && echo $(p))))
endif
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
# Where `make bench` writes its tables (the committed ones in bench/ stay as they are).
BENCH_OUT := out/bench

.PHONY: demo demo-loop demo-offline test test-fast typecheck warmup bench docs clean \
	upgrade-deps check-python control-msgs docs-regenerate

# The install also compiles the numba kernels into their on-disk cache (dcmotor_id.cli.warmup),
# and the identify path's kernels ahead of time (dcmotor_id/simulation/compiled.py, needs a C
# compiler): the user's first `dcmotor-id identify` then runs as fast as the second one, and
# without importing numba.
# The versions come from constraints.txt (the ones the tests passed on; `make upgrade-deps`).
$(STAMP): requirements.txt constraints.txt setup.py setup.cfg package.xml
	test -x $(PY) || $(MAKE) --no-print-directory check-python
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	@echo "installing the dependencies into $(VENV) (a few minutes on a fresh machine; pip shows each package)"
	$(PY) -m pip install --progress-bar off -r requirements.txt -c constraints.txt
	$(PY) -m pip install --quiet --no-deps -e .
	$(PY) -m dcmotor_id.cli.warmup
	touch $(STAMP)

check-python:
	@test -n "$(PYTHON)" || { echo "no Python 3.11 or 3.12 found (tried python3.12," \
	    "python3.11, python3): install one, or name it: make PYTHON=/path/to/python3.12" >&2; \
	    exit 2; }
	@$(PYTHON) -c '$(SUPPORTED_PYTHON)' || echo "$(PYTHON) is not Python 3.11 or 3.12, the" \
	    "versions the ROS 2 Jazzy wheels exist for; trying anyway" >&2

# Upgrade the venv to the newest versions requirements.txt allows and write them to
# constraints.txt; then run `make test` and commit constraints.txt if it passes.
upgrade-deps: $(STAMP)
	$(PY) -m pip install --progress-bar off --upgrade -r requirements.txt
	$(PY) tools/freeze_constraints.py > constraints.txt.new
	mv constraints.txt.new constraints.txt
	@echo "constraints.txt regenerated: run make test, then commit it if the tests pass"

# Recompile the numba cache and the ahead-of-time module by hand (after editing a kernel, say).
warmup: $(STAMP)
	$(PY) -m dcmotor_id.cli.warmup

# control_msgs' DynamicJointState for the identifier's input dynamic_joint_state: the ROS wheels
# have none, so tools/build_control_msgs.sh generates it from control_msgs' .msg files with the
# rosidl generators (requirements-control-msgs.txt) into the venv (needs cmake and a C++
# compiler, about a minute). `make test` does it first (the node tests of that input); on a ROS
# machine install ros-jazzy-control-msgs instead.
CONTROL_MSGS_STAMP := $(VENV)/.control-msgs-stamp
control-msgs: $(CONTROL_MSGS_STAMP)

$(CONTROL_MSGS_STAMP): $(STAMP) requirements-control-msgs.txt tools/build_control_msgs.sh \
		tools/control_msgs/CMakeLists.txt tools/control_msgs/package.xml \
		$(wildcard tools/control_msgs/msg/*.msg)
	$(PY) -m pip install --progress-bar off -r requirements-control-msgs.txt -c constraints.txt
	bash tools/build_control_msgs.sh $(VENV)
	touch $@

# The real node graph: sim_motor and identifier as processes, recording, then ~/identify.
demo: $(STAMP)
	$(PY) -m dcmotor_id.nodes.demo

# The excitation loop: plan -> exciter -> sim_motor -> identifier, expected vs achieved stderr.
demo-loop: $(STAMP)
	$(PY) -m dcmotor_id.nodes.loop_demo

# The offline comparison of the paper's method and the default one (no ROS).
demo-offline: $(STAMP)
	$(VENV)/bin/dcmotor-id demo

# Everything: the type check, then every test (pytest's exit code, 5 when none is collected).
test: typecheck control-msgs
	$(PY) -m pytest -q -ra

# The inner loop: no ROS graph, nothing slower than a few seconds.
test-fast: $(STAMP)
	$(PY) -m pytest -q -ra -m 'not ros and not slow'

typecheck: $(STAMP)
	$(PY) -m mypy

# The manual (docs/, Sphinx with MyST pages and API pages from the docstrings) as HTML in
# docs/_build/html; any warning fails the build (test/test_docs.py builds it the same way).
docs: $(STAMP)
	$(PY) -m sphinx -b html -W --keep-going docs docs/_build/html
	@echo "the manual: docs/_build/html/index.html"

# The command output, report figures and quoted bench numbers the manual shows, regenerated
# from the current code and bench tables (tools/generate_docs.py; test/test_docs_generated.py
# fails until they are).
docs-regenerate: $(STAMP)
	$(PY) tools/generate_docs.py

# The simulated benchmarks of bench/README.md, each table written to $(BENCH_OUT) under its
# committed name (long: about an hour).
bench: $(STAMP)
	mkdir -p $(BENCH_OUT)
	$(PY) bench/bench_replication.py > $(BENCH_OUT)/replication_results.md
	$(PY) bench/bench_sampling_period.py > $(BENCH_OUT)/sampling_period_results.md
	$(PY) bench/bench_noise.py > $(BENCH_OUT)/noise_results.md
	$(PY) bench/bench_speed.py > $(BENCH_OUT)/speed_results.md
	$(PY) bench/bench_online.py > $(BENCH_OUT)/online_results.md
	$(PY) bench/bench_discovery.py --out $(BENCH_OUT)/discovery_results.md
	$(PY) bench/bench_throughput.py --out $(BENCH_OUT)/throughput_results.md
	$(PY) bench/bench_cold_start.py --out $(BENCH_OUT)/cold_start_results.md
	$(PY) bench/bench_experiment.py > $(BENCH_OUT)/experiment_results.md

clean:
	rm -rf $(VENV) build install log docs/_build

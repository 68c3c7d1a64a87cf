# Two commands set everything up on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
# Where `make bench` writes its tables (the committed ones in bench/ stay as they are).
BENCH_OUT := out/bench

.PHONY: demo demo-loop demo-offline test test-fast typecheck warmup bench docs clean

# The install also compiles the numba kernels into their on-disk cache (dcmotor_id.cli.warmup),
# and the identify path's kernels ahead of time (dcmotor_id/simulation/compiled.py, needs a C
# compiler): the user's first `dcmotor-id identify` then runs as fast as the second one, and
# without importing numba.
$(STAMP): requirements.txt setup.py setup.cfg package.xml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	@echo "installing the dependencies into $(VENV) (a few minutes on a fresh machine; pip shows each package)"
	$(PY) -m pip install --progress-bar off -r requirements.txt
	$(PY) -m pip install --quiet --no-deps -e .
	$(PY) -m dcmotor_id.cli.warmup
	touch $(STAMP)

# Recompile the numba cache and the ahead-of-time module by hand (after editing a kernel, say).
warmup: $(STAMP)
	$(PY) -m dcmotor_id.cli.warmup

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
test: typecheck
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

# Two commands set everything up on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp

.PHONY: demo demo-offline test bench clean

$(STAMP): requirements.txt setup.py setup.cfg package.xml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.txt
	$(PY) -m pip install --quiet --no-deps -e .
	touch $(STAMP)

# The real node graph: sim_motor and identifier as processes, recording, then ~/identify.
demo: $(STAMP)
	$(PY) -m dcmotor_id.nodes.demo

# The offline comparison of the paper's method and the default one (no ROS).
demo-offline: $(STAMP)
	$(VENV)/bin/dcmotor-id demo

test: $(STAMP)
	$(PY) -m pytest -q -ra

clean:
	rm -rf $(VENV) build install log

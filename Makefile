# Two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
PY      = $(VENV)/bin/python
SAMPLE  = samples/demo

.PHONY: venv demo test clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $@

venv: $(VENV)/.installed

# Render a sample pipe run with known ground truth and report it.
demo: venv
	$(PY) -m hw_sim render --out samples --name demo --tilt 24 --speed 0.2 --duration 5

test: venv
	$(PY) -m pytest -q

clean:
	rm -rf $(VENV) samples out

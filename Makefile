# Two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
PY      = $(VENV)/bin/python
SAMPLE  = samples/demo

.PHONY: venv demo test clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[pc,test]'
	touch $@

venv: $(VENV)/.installed

# Render a sample pipe run with known ground truth, then measure it with crawlerd --replay.
demo: venv
	$(PY) -m hw_sim render --out samples --name demo --tilt 24 --speed 0.2 --duration 5
	$(VENV)/bin/crawlerd --replay $(SAMPLE).h264 --tilt 24 --log $(SAMPLE).jsonl --annotate $(SAMPLE)-annotated.mp4
	@$(PY) -c "import json; t=json.load(open('$(SAMPLE).json'))['true_distance_m']; \
	  m=[json.loads(l) for l in open('$(SAMPLE).jsonl')][-1]['distance_m']; \
	  print(f'true distance {t:.4f} m, measured {m:.4f} m, error {100*(m-t)/t:+.4f} %')"

test: venv
	$(PY) -m pytest -q

clean:
	rm -rf $(VENV) samples out

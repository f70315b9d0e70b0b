# The two commands of the README: `make demo` and `make test`. Both build .venv themselves.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(VENV)/bin/pip

.PHONY: demo test lint clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --quiet --upgrade pip
	$(PIP) install --quiet -e '.[test]'
	touch $@

.venv: $(VENV)/.installed

demo: .venv
	$(VENV)/bin/cdpr run caroca_15kg --rrd runs/caroca_15kg.rrd --summary runs/caroca_15kg.summary.json

test: .venv
	$(PY) -m pytest $(PYTEST_ARGS)

lint: .venv
	$(VENV)/bin/ruff check . || true

clean:
	rm -rf $(VENV) runs build *.egg-info

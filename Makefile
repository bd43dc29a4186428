# Two entry points that work on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test test-slow test-latest lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

setup: $(STAMP)

## demo: the baffle study on built-in defaults, report written to report/
demo: $(STAMP)
	$(VENV)/bin/straylight study --out report

## test: the default (fast) test suite
test: $(STAMP)
	$(PY) -m pytest -q -n 2

## lint: ruff and mypy on the whole tree (pyproject.toml [tool.ruff] / [tool.mypy])
LINTED := atomicio materials geometry straylight rig
lint: $(STAMP)
	$(VENV)/bin/ruff check $(LINTED)
	$(VENV)/bin/mypy $(LINTED)

## test-latest: the engine's tests on the newest numba and dask/distributed, past the upper bounds (.ci/latest)
test-latest:
	.ci/latest

## test-slow: only the long physics checks marked @pytest.mark.slow (the default suite deselects them)
test-slow: $(STAMP)
	$(PY) -m pytest -q -n 2 -m slow

bench: $(STAMP)
	$(PY) benchmarks/throughput.py

clean:
	rm -rf $(VENV) report

# Every target creates .venv when it is missing and installs the project into it,
# so a fresh clone needs only python3 >= 3.11, pip and make.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench fuzz clean

$(STAMP): pyproject.toml Makefile
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	# compat: a path entry for the checkout (python -m … from any directory, no setuptools
	# warning about same-named folders on every install)
	$(PY) -m pip install --quiet -e '.[test,plot,xsd]' --config-settings editable_mode=compat
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m cell demo

lint: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .
	$(PY) -m mypy

# Two workers: the suite is mostly waiting (sockets, subprocesses, real-time runs), and the
# real-time tests hold up with the other worker busy beside them (they must: #12).
test: lint
	$(PY) -m pytest -n 2

# The peer libraries of the benchmarks only here: `make test` must not need them.
$(VENV)/.installed-bench: $(STAMP)
	$(PY) -m pip install --quiet -e '.[test,plot,xsd,bench]' --config-settings editable_mode=compat
	touch $@

bench: $(VENV)/.installed-bench
	$(PY) -m bench -o bench-results/results.json

fuzz: $(STAMP)
	$(PY) -m spec fuzz --count 200000 --seed 1

clean:
	rm -rf $(VENV) bench-results .pytest_cache .mypy_cache .ruff_cache

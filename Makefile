# Every target creates .venv when it is missing and installs the project into it,
# so a fresh clone needs only python3 >= 3.11, pip and make.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test lint chromium tshark bench fuzz clean

$(STAMP): pyproject.toml Makefile
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	# PYTHONWARNINGS: setuptools warns on every editable install that the checkout's folders
	# share the packages' names, which is this layout by design; the warning tells a user nothing.
	PYTHONWARNINGS=ignore $(PY) -m pip install --quiet -e '.[test,plot,xsd,console,fast]'
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m cell demo

lint: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .
	$(PY) -m mypy

# Two workers: the suite is mostly waiting (sockets, subprocesses, real-time runs), and the
# real-time tests hold up with the other worker busy beside them (they must: #12). worksteal:
# a worker that runs dry takes half of the other's queue; tests/conftest.py starts each worker's
# slice with its share of the long tests, so the run does not end with one worker idle beside a
# long test.
#
# Lint runs beside the tests, niced, its report printed after theirs: mypy's cold start in a
# clean clone (about 15 s of one core) fits in the CPU the mostly-waiting suite leaves idle (it
# uses about half of two cores), and nice keeps it from taking CPU the real-time tests need.
# Either failing fails the target.
test: $(STAMP) chromium tshark
	@log=$$(mktemp); nice -n 10 $(MAKE) --no-print-directory lint >"$$log" 2>&1 & lint=$$!; \
	$(PY) -m pytest -n 2 --dist worksteal; tests=$$?; \
	wait $$lint; linted=$$?; cat "$$log"; rm -f "$$log"; \
	if [ $$linted -ne 0 ]; then echo "make lint failed (exit $$linted)"; fi; \
	exit $$(( tests != 0 ? tests : linted ))

# The console's browser tests drive Debian's chromium (no browser download): installed here
# when missing and we are root (CI on a fresh machine), else they are skipped, loudly.
chromium:
	@if [ -x /usr/bin/chromium ]; then :; \
	elif [ "$$(id -u)" = 0 ]; then export DEBIAN_FRONTEND=noninteractive; \
		apt-get install -y chromium || { apt-get update && apt-get install -y chromium; } || \
		echo "BROWSER TESTS WILL BE SKIPPED: apt-get could not install chromium"; \
	else echo "BROWSER TESTS WILL BE SKIPPED: /usr/bin/chromium not installed (not root)"; fi

# The dissector's tests run Debian's tshark: installed as chromium is (root, non-interactive;
# the wireshark-common question about non-root capture is answered "no" by the frontend).
tshark:
	@if command -v tshark >/dev/null; then :; \
	elif [ "$$(id -u)" = 0 ]; then export DEBIAN_FRONTEND=noninteractive; \
		apt-get install -y tshark || { apt-get update && apt-get install -y tshark; } || \
		echo "TSHARK TESTS WILL BE SKIPPED: apt-get could not install tshark"; \
	else echo "TSHARK TESTS WILL BE SKIPPED: tshark not installed (not root)"; fi

# The peer libraries of the benchmarks only here: `make test` must not need them.
$(VENV)/.installed-bench: $(STAMP)
	PYTHONWARNINGS=ignore $(PY) -m pip install --quiet -e '.[test,plot,xsd,console,fast,bench]'
	touch $@

# Ends with the targets: exit 0 all met, else bench.table's --check status (4 missed, 5 undecided).
bench: $(VENV)/.installed-bench
	$(PY) -m bench -o bench-results/results.json
	$(PY) -m bench.table --check bench-results/results.json

fuzz: $(STAMP)
	$(PY) -m spec fuzz --count 200000 --seed 1

clean:
	rm -rf $(VENV) bench-results .pytest_cache .mypy_cache .ruff_cache

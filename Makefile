# One command each: `make test` and `make demo` create/refresh .venv and install what they need.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: test test-all demo venv bench clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[build,sitl,test,systemd,docs]'
	@touch $(STAMP)

venv: $(STAMP)

# one pytest worker per core (pytest-xdist); a test file's tests stay on one worker (its module fixtures built once)
XDIST  := -n auto --dist loadfile

test: $(STAMP)
	$(PY) -m pytest -q $(XDIST)

test-all: $(STAMP)  # the slow campaigns and flights too
	$(PY) -m pytest -q $(XDIST) -m "slow or not slow"

demo: $(STAMP)
	$(VENV)/bin/contract-guard demo

bench: $(STAMP)
	$(PY) benchmarks/bench_lookup.py

clean:
	rm -rf $(VENV) build *.egg-info

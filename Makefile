# One command each: `make test` and `make demo` create/refresh .venv and install what they need.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: test test-all demo venv bench clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[ground,build,sitl,test,systemd,docs]'
	@touch $(STAMP)

venv: $(STAMP)

# pytest-xdist: one worker more than the cores (a third of the suite waits on real time: UDP, real processes);
# a test file's tests stay on one worker (its module fixtures built once)
XDIST  := -n $(shell echo $$(( $$(nproc 2>/dev/null || echo 1) + 1 ))) --dist loadfile

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

# Two commands do all the set-up on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test bench docs clean

# Python writes its bytecode caches (__pycache__, ignored by git) even where the environment says
# not to: every `aspod` child of the tests and benches would otherwise compile the package anew.
unexport PYTHONDONTWRITEBYTECODE

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[test,bench,compiled,plot,fuzz,campaign,reference,foxglove]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/aspod demo

# pytest-xdist, a worker per core and one more; tests/conftest.py orders the tests and keeps the CPU hogs apart.
# OpenBLAS single-threaded: the workers are the parallelism. Its own threads spin while they wait: on 2 cores the
# planner's tests took 56 s with them and 41 s without, and starved the real-time tests beside them.
test: $(STAMP)
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(BIN)/python -m pytest -n auto --dist load

bench: $(STAMP)
	$(BIN)/python -m bench

docs: $(STAMP)
	$(BIN)/python -m protocol.docgen > docs/protocol.md
	$(BIN)/python -m host_tools.cli.main schema --json --output docs/schema.json
	$(BIN)/python -m host_tools.sessions.vectors

clean:
	rm -rf $(VENV) build *.egg-info

# Quickstart: `make demo` and `make test` do all set-up on a fresh machine.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test bench clean venv

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test,bench]'
	$(BIN)/python -m compileall -q src  # bytecode, as a regular install has (PYTHONDONTWRITEBYTECODE)
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(BIN)/facetransfer demo --out out --overwrite

test: $(STAMP)
	$(BIN)/python -m pytest -q -p no:cacheprovider tests

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do $(BIN)/python $$b --out out/benchmarks || exit 1; done

clean:
	rm -rf $(VENV) out build src/*.egg-info

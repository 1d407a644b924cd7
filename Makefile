# ropemon: the two commands a new user runs are `make demo` and `make test`.
# Everything they need is installed here, into .venv and node_modules, pinned.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
NODE_STAMP := node_modules/.installed

.PHONY: all demo test test-host test-firmware bench evaluate clean

all: test

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[lab,test]'
	touch $@

# The official 32-bit MicroPython (WebAssembly port), used to prove 32-bit int safety.
$(NODE_STAMP): package.json package-lock.json
	npm ci --no-audit --no-fund --loglevel=error
	touch $@

demo: $(STAMP)
	$(BIN)/ropemon demo

test: $(STAMP) $(NODE_STAMP)
	$(BIN)/python -m pytest
	$(BIN)/python tests/run_micropython.py

bench: $(STAMP)
	$(BIN)/ropemon bench firmware
	$(BIN)/ropemon bench plant
	$(BIN)/ropemon bench host

# The named scenarios, then the population of drawn hoists on the scoring seeds; their tables
# go to docs/evaluation/ (generated: each file's first line names the command that made it).
evaluate: $(STAMP)
	$(BIN)/ropemon evaluate --out out/evaluate
	$(BIN)/ropemon evaluate --population 100 --seeds scoring --out out/evaluate
	mkdir -p docs/evaluation
	cp out/evaluate/accuracy.md docs/evaluation/scenarios.md
	cp out/evaluate/population.md docs/evaluation/population.md

clean:
	rm -rf $(VENV) node_modules out

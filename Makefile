# viscover: `make test` and `make demo` work from a fresh clone (they create .venv themselves).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: all venv test demo bench lint typecheck clean

all: test

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

lint: $(STAMP)
	$(BIN)/ruff check agent groundstation tests bench

typecheck: $(STAMP)
	$(BIN)/mypy

test: $(STAMP) lint typecheck
	$(BIN)/python -m pytest -q

demo: $(STAMP)
	$(BIN)/viscover launch scenarios/cube_6_2.toml --flight --runs out/runs --timeout 180
	$(BIN)/viscover simulate scenarios/cube_6_2.toml --out out/demo
	@echo "Run folder in out/runs/ (logs, journals, observer.json); report in out/demo/."

bench: $(STAMP)
	$(BIN)/python -m bench.run $(BENCH)

clean:
	rm -rf $(VENV) out .pytest_cache .ruff_cache .mypy_cache

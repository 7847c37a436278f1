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

# Two pytest workers, one test file each at a time: most tests wait on processes and clocks,
# so two share this 2-core machine well. The timing-sensitive multi-process missions
# (marker "serial") then run alone. About 6.5 minutes instead of 9.5.
test: $(STAMP) lint typecheck
	$(BIN)/python -m pytest -q -n 2 --dist loadfile -m "not serial"
	$(BIN)/python -m pytest -q -m serial

# The thesis' cube flown as a launched multi-process mission, recorded, then its report built
# from the recording (the report is written even when the mission did not complete; make
# then fails with the launch's status).
demo: $(STAMP)
	rm -rf out/demo
	$(BIN)/viscover launch scenarios/cube_6_2.toml --flight --runs out/demo --timeout 180; \
	status=$$?; run=$$(ls -d out/demo/cube_6_2-*); \
	$(BIN)/viscover report $$run && \
	echo "Run folder $$run: recording.mcap (open it in Foxglove), events.jsonl, logs, journals;" \
	     "report in $$run/report/ (report.html)."; \
	exit $$status

bench: $(STAMP)
	$(BIN)/python -m bench.run $(BENCH)

clean:
	rm -rf $(VENV) out .pytest_cache .ruff_cache .mypy_cache

# viscover: `make test` and `make demo` work from a fresh clone (they create .venv themselves).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: all venv test demo bench chaos chaos-hostile lint typecheck clean browser

all: test

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

lint: $(STAMP)
	$(BIN)/ruff check agent groundstation viscover tests bench

typecheck: $(STAMP)
	$(BIN)/mypy

# A headless browser for the report page's screenshot test (tests/test_report_page.py), best
# effort: Debian's chromium-headless-shell when running as root with apt-get; otherwise that
# one check skips (the page's structural tests always run).
browser:
	@command -v chromium-headless-shell >/dev/null 2>&1 || command -v chromium >/dev/null 2>&1 || \
	{ [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
	  { timeout 300 apt-get install -y -qq chromium-headless-shell >/dev/null 2>&1 || \
	    { timeout 300 apt-get update -qq >/dev/null 2>&1 && \
	      timeout 300 apt-get install -y -qq chromium-headless-shell >/dev/null 2>&1; }; }; } || \
	echo "make: no headless Chromium (apt-get install chromium-headless-shell): the report" \
	     "page's screenshot test will skip"

# Two pytest workers, one test file each at a time: most tests wait on processes and clocks,
# so two share this 2-core machine well. The timing-sensitive multi-process missions
# (marker "serial") then run alone. About 6 minutes, then 3.5 (measured on this 2-core machine
# while it ran other work too).
test: $(STAMP) lint typecheck browser
	$(BIN)/python -m pytest -q -n 2 --dist loadfile -m "not serial and not long"
	$(BIN)/python -m pytest -q -m "serial and not long"

# Whole flown missions of minutes each (potential flown, inspections indoors and outdoors),
# and the cases make test leaves to a faster test of the same property (each names it at its
# marker: the lossless twin of a lossy run, other structures, other seeds), alone: outside
# make test's 12-minute budget.
test-long: $(STAMP)
	$(BIN)/python -m pytest -q -m long

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

# Chaos campaign (not in `make test`): seeded runs of a secured mission of real processes
# under kills, stops, partitions, disk faults and a hostile authenticated drone at once; a
# table of faults, lost, doubled, violations, incomplete (JSON lines in bench/results.jsonl).
# CHAOS="--runs 12 --seed 1" for more.
CHAOS ?= --runs 8
chaos: $(STAMP)
	$(BIN)/python -m bench.chaos $(CHAOS)

# issue 33: an insider holding a drone's certificate and key, every attack (CHAOS_HOSTILE="--runs 4")
chaos-hostile: $(STAMP)
	$(BIN)/python -m bench.chaos_insider $(CHAOS_HOSTILE)

clean:
	rm -rf $(VENV) out .pytest_cache .ruff_cache .mypy_cache

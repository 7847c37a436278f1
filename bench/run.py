"""`make bench`: run every benchmark, print one JSON object per line, keep them in
bench/results.jsonl (one line per measurement, each stamped with the time of the run)."""

from __future__ import annotations

import importlib
import io
import json
import sys
import time
from pathlib import Path

#: Benchmark modules, each with ``run(out)``; a module not yet written is reported, not skipped.
MODULES = ("bench.bench_planner", "bench.bench_net", "bench.bench_trade", "bench.bench_flight",
           "bench.bench_occlusion", "bench.bench_quality", "bench.bench_security",
           "bench.bench_adoption", "bench.bench_loss", "bench.bench_inspection",
           "bench.bench_ros2", "bench.bench_startup", "bench.bench_decisions",
           "bench.bench_prepare", "bench.bench_traffic", "bench.bench_team")


class _Tee(io.TextIOBase):
    """Writes to stdout and remembers every line."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self._buf = ""

    def write(self, s: str) -> int:
        sys.stdout.write(s)
        sys.stdout.flush()
        self._buf += s
        *done, self._buf = self._buf.split("\n")
        self.lines.extend(line for line in done if line.strip())
        return len(s)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmarks named in argv (default: all) and append to bench/results.jsonl."""
    names = argv if argv else list(MODULES)
    stamp = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    tee = _Tee()
    failed = 0
    for name in names:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            print(json.dumps({"bench": name, "error": f"not available: {exc}"}))
            failed += 1
            continue
        module.run(tee)
    out = Path(__file__).with_name("results.jsonl")
    with out.open("a", encoding="utf-8") as fh:
        for line in tee.lines:
            rec = json.loads(line)
            rec["run_at"] = stamp
            fh.write(json.dumps(rec) + "\n")
    print(f"# {len(tee.lines)} measurements appended to {out}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""Network micro-benchmark: bare Zenoh get round trip through a Python router on loopback.

``run(out)`` starts a router on a free loopback port, connects two client sessions, declares
a queryable on one that replies from a worker thread (as :class:`agent.net.ZenohTransport`
does, the queries being handed off the Zenoh thread), and times ``n`` ``session.get`` calls
with a 64-byte payload from the other. Prints one JSON line per measurement, e.g.
``{"bench": "zenoh_get_rtt", "median_s": 0.0005, "p99_s": 0.002, "n": 1000}``; times in seconds.

Run: ``python -m bench.bench_net [--n 1000]``.
"""

from __future__ import annotations

import argparse
import json
import queue
import statistics
import sys
import threading
import time
from typing import Any, TextIO

import zenoh

from agent.net.router import client_config, start_router_process, stop_router_process
from agent.net.transport import ZenohTransport

KEY = "viscover/bench/trade/server"


def _percentile(samples: list[float], q: float) -> float:
    ordered = sorted(samples)
    idx = min(len(ordered) - 1, max(0, round(q * (len(ordered) - 1))))
    return ordered[idx]


def _emit(out: TextIO, record: dict[str, Any]) -> None:
    out.write(json.dumps(record) + "\n")
    out.flush()


def _stats(name: str, rtts: list[float], n: int, **extra: Any) -> dict[str, Any]:
    return {
        "bench": name,
        "median_s": statistics.median(rtts) if rtts else None,
        "p99_s": _percentile(rtts, 0.99) if rtts else None,
        "n": n,
        "lost": n - len(rtts),
        **extra,
    }


def bench_bare_get(endpoint: str, n: int, payload: bytes, timeout_s: float) -> list[float]:
    """Round trips (seconds) of ``n`` bare ``session.get`` calls; lost ones are left out."""
    pending: queue.SimpleQueue[zenoh.Query | None] = queue.SimpleQueue()

    def serve() -> None:
        while (query := pending.get()) is not None:
            with query:
                pl = query.payload
                query.reply(KEY, pl.to_bytes() if pl is not None else b"")

    rtts: list[float] = []
    # Leaving the with closes the client, then the server (once the worker has stopped).
    with (zenoh.open(client_config(endpoint)) as server,
          zenoh.open(client_config(endpoint)) as client):
        worker = threading.Thread(target=serve, name="bench-queryable", daemon=True)
        worker.start()
        try:
            server.declare_queryable(KEY, pending.put)
            deadline = time.monotonic() + 10.0
            while not any(r.ok for r in client.get(KEY, payload=payload, timeout=0.5)):
                if time.monotonic() > deadline:
                    raise TimeoutError("queryable not reachable through the router")
            for _ in range(20):  # warm-up
                list(client.get(KEY, payload=payload, timeout=timeout_s))
            for _ in range(n):
                t0 = time.perf_counter()
                ok = any(r.ok for r in client.get(KEY, payload=payload, timeout=timeout_s))
                dt = time.perf_counter() - t0
                if ok:
                    rtts.append(dt)
        finally:
            pending.put(None)
            worker.join(5.0)
    return rtts


def bench_transport_request(endpoint: str, n: int, payload: bytes, timeout_s: float) -> list[float]:
    """Round trips (seconds) of ``n`` :meth:`ZenohTransport.request` calls."""
    server = ZenohTransport(client_config(endpoint), node_id="server")
    client = ZenohTransport(client_config(endpoint), node_id="client")
    rtts: list[float] = []
    try:
        server.declare_queryable(KEY, lambda p, _s: p)
        deadline = time.monotonic() + 10.0
        while client.request(KEY, payload, 0.5) is None:
            if time.monotonic() > deadline:
                raise TimeoutError("queryable not reachable through the router")
        for _ in range(20):
            client.request(KEY, payload, timeout_s)
        for _ in range(n):
            t0 = time.perf_counter()
            ok = client.request(KEY, payload, timeout_s) is not None
            dt = time.perf_counter() - t0
            if ok:
                rtts.append(dt)
    finally:
        client.close()
        server.close()
    return rtts


def run(out: TextIO | None = None, n: int = 1000, payload_bytes: int = 64) -> list[dict[str, Any]]:
    """Run the network benchmarks, printing one JSON object per line to ``out`` (stdout)."""
    stream = out if out is not None else sys.stdout
    payload = bytes(payload_bytes)
    timeout_s = 2.0
    proc, endpoint = start_router_process()
    records: list[dict[str, Any]] = []
    try:
        rtts = bench_bare_get(endpoint, n, payload, timeout_s)
        records.append(_stats("zenoh_get_rtt", rtts, n, payload_bytes=payload_bytes))
        _emit(stream, records[-1])
        rtts = bench_transport_request(endpoint, n, payload, timeout_s)
        records.append(_stats("transport_request_rtt", rtts, n, payload_bytes=payload_bytes))
        _emit(stream, records[-1])
    finally:
        stop_router_process(proc)
    return records


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, default=1000, help="requests per benchmark")
    parser.add_argument("--payload-bytes", type=int, default=64)
    args = parser.parse_args(argv)
    run(sys.stdout, n=args.n, payload_bytes=args.payload_bytes)
    return 0


if __name__ == "__main__":
    sys.exit(main())

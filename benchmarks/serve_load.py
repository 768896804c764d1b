"""A served model under load: latency and the server's memory with several clients at once.

Starts ``svbrdf-models serve`` (the shipped model unless ``--model``) on loopback, then for each
configuration sends ``--requests`` photos from ``--clients`` threads at once, each its own photo
of random linear values, and prints a Markdown table: requests, errors (any answer but 200),
median and 95th-percentile latency, requests per second, and the server's peak resident memory
(``VmHWM`` of its process, so it only grows from row to row). The server runs with the default
limits; on a shared machine the latencies are not timings: run it idle.

Usage::

    .venv/bin/python benchmarks/serve_load.py                           # 4 clients, 64 px, refine 0 and 20
    .venv/bin/python benchmarks/serve_load.py --clients 8 --size 256 --refine 0
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from concurrent.futures import ThreadPoolExecutor

import numpy as np


def peak_mb(pid: int | None) -> float:
    """The peak resident memory of process ``pid`` in MB (Linux's VmHWM); NaN where unknown."""
    try:
        with open(f"/proc/{pid}/status") as f:
            line = next(x for x in f if x.startswith("VmHWM:"))
        return int(line.split()[1]) / 1024
    except (OSError, StopIteration, TypeError):
        return float("nan")


def _one(url: str, body: bytes) -> tuple[float, int]:
    request = urllib.request.Request(
        url + "/invocations", data=body, headers={"Content-Type": "application/json"}
    )
    start = time.perf_counter()
    try:
        with urllib.request.urlopen(request, timeout=300) as response:
            response.read()
            status = response.status
    except urllib.error.HTTPError as e:
        status = e.code
    except OSError:
        status = 0
    return time.perf_counter() - start, status


def load_test(
    url: str, clients: int, requests: int, size: int, refine: int = 0, pid: int | None = None
) -> dict:
    """``requests`` POSTs of ``size`` px photos from ``clients`` threads; latency percentiles,
    errors, throughput and the server's peak memory (``pid``)."""
    rng = np.random.default_rng(0)
    bodies = [
        json.dumps(
            {
                "inputs": rng.uniform(0.02, 0.9, (1, size, size, 3)).round(4).tolist(),
                "params": {"refine": refine},
            }
        ).encode()  # fmt: skip
        for _ in range(min(requests, 8))
    ]
    start = time.perf_counter()
    with ThreadPoolExecutor(clients) as pool:
        results = list(pool.map(lambda i: _one(url, bodies[i % len(bodies)]), range(requests)))
    wall = time.perf_counter() - start
    seconds = np.array([s for s, _ in results])
    return {
        "requests": requests,
        "errors": sum(status != 200 for _, status in results),
        "p50_s": float(np.percentile(seconds, 50)),
        "p95_s": float(np.percentile(seconds, 95)),
        "per_s": requests / wall,
        "peak_mb": peak_mb(pid),
    }


def table(rows: list[tuple[str, dict]]) -> str:
    """The figures of :func:`load_test` as a Markdown table, one row per configuration."""
    lines = ["| load | requests | errors | p50 s | p95 s | requests/s | server peak MB |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"]  # fmt: skip
    for name, f in rows:
        lines.append(f"| {name} | {f['requests']} | {f['errors']} | {f['p50_s']:.2f} | {f['p95_s']:.2f} | "
                     f"{f['per_s']:.1f} | {f['peak_mb']:.0f} |")  # fmt: skip
    return "\n".join(lines)


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="pretrained")
    parser.add_argument("--clients", type=int, default=4)
    parser.add_argument("--requests", type=int, default=100)
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--refine", default="0,20", help="refinement budgets, one row each")
    args = parser.parse_args()
    port = _free_port()
    url = f"http://127.0.0.1:{port}"
    exe = os.path.join(os.path.dirname(sys.executable), "svbrdf-models")
    proc = subprocess.Popen([exe, "serve", args.model, "--port", str(port)], stdout=subprocess.DEVNULL)
    try:
        for _ in range(600):
            try:
                urllib.request.urlopen(url + "/ping", timeout=2).read()
                break
            except OSError:
                time.sleep(0.2)
        rows = []
        for refine in (int(r) for r in args.refine.split(",")):
            n = args.requests if refine == 0 else max(args.clients, args.requests // 5)
            figures = load_test(url, args.clients, n, args.size, refine, proc.pid)
            rows.append((f"{args.clients} clients, {args.size} px, refine {refine}", figures))
        print(table(rows))
    finally:
        proc.terminate()
        proc.wait(30)


if __name__ == "__main__":
    main()

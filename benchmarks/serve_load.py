"""A served model under load: latency and the server's memory with several clients at once.

Starts ``svbrdf-models serve`` (the shipped model unless ``--model``) on loopback, then for each
configuration sends ``--requests`` photos from ``--clients`` threads at once, each its own photo
of random linear values, and prints a Markdown table: requests, errors (any answer but 200),
median and 95th-percentile latency, requests per second, and the server's peak resident memory
(``VmHWM`` of its process, so it only grows from row to row). The server runs with the default
limits; on a shared machine the latencies are not timings: run it idle.

``--cases`` sends instead the single requests a hostile tester sent (issue 47), each alone, and
prints what the server answered, the worker's busy time (the ``work`` stage of the answer's
``Server-Timing``, or, when the answer came before the work ended, how long a small request sent
next waited for the worker) and the server's peak memory during the request, sampled every
0.1 s: its own resident memory and that of its process tree (the child that parses large
bodies included), against the default limits:

- ``photos-1024``: 1024 photos of 64x64 in one request (exactly ``--max-pixels``);
- ``photo-2048``: one 2048x2048 photo at refine 1;
- ``photo-1024``: one 1024x1024 photo at refine 500 (the largest kind the defaults take).

Usage::

    .venv/bin/python benchmarks/serve_load.py                           # 4 clients, 64 px, refine 0 and 20
    .venv/bin/python benchmarks/serve_load.py --clients 8 --size 256 --refine 0
    .venv/bin/python benchmarks/serve_load.py --cases photos-1024,photo-2048 --threads 1
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import threading
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


def _rss_mb(pid: int) -> float:
    """The resident memory of process ``pid`` in MB (Linux's VmRSS); 0 where it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            return int(next(x for x in f if x.startswith("VmRSS:")).split()[1]) / 1024
    except (OSError, StopIteration):
        return 0.0


def _pss_mb(pid: int) -> float:
    """The proportional set size of process ``pid`` in MB (its pages, those it shares counted
    in part: a forked child's are mostly its parent's); 0 where it is gone."""
    try:
        with open(f"/proc/{pid}/smaps_rollup") as f:
            return int(next(x for x in f if x.startswith("Pss:")).split()[1]) / 1024
    except (OSError, StopIteration):
        return 0.0


def _tree(pid: int) -> list[int]:
    """``pid`` and every process below it (children of its threads, their children...)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as f:
                    todo += [int(c) for c in f.read().split()]
        except OSError:
            continue
    return out


class MemorySampler:
    """The peak memory of a process, sampled every ``every`` seconds on a thread while the
    ``with`` block runs: its resident memory (``server_mb``) and the proportional set size of
    its process tree (``tree_mb``: the process and the children it forked, shared pages counted
    once)."""

    def __init__(self, pid: int, every: float = 0.1):
        self.pid, self.every, self.server_mb, self.tree_mb = pid, every, 0.0, 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def _sample(self) -> None:
        while True:
            self.server_mb = max(self.server_mb, _rss_mb(self.pid))
            self.tree_mb = max(self.tree_mb, sum(_pss_mb(p) for p in _tree(self.pid)))
            if self._stop.wait(self.every):
                return

    def __enter__(self) -> MemorySampler:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


class PingProbe:
    """The slowest ``GET /ping`` while the ``with`` block runs, one every ``every`` seconds on a
    thread (``worst_s``): how long the event loop was held."""

    def __init__(self, url: str, every: float = 0.25):
        self.url, self.every, self.worst_s = url, every, 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._probe, daemon=True)

    def _probe(self) -> None:
        while not self._stop.wait(self.every):
            start = time.perf_counter()
            try:
                urllib.request.urlopen(self.url + "/ping", timeout=120).read()
            except OSError:
                pass
            self.worst_s = max(self.worst_s, time.perf_counter() - start)

    def __enter__(self) -> PingProbe:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


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


#: The single requests of ``--cases``: name -> (photos, side, refinement steps, what it is).
CASES = {
    "photos-1024": (1024, 64, 0, "1024 photos of 64x64 in one request"),
    "photo-2048": (1, 2048, 1, "one 2048x2048 photo at refine 1"),
    "photo-1024": (1, 1024, 500, "one 1024x1024 photo at refine 500"),
}


def _body(photos: int, side: int, refine: int) -> bytes:
    values = np.random.default_rng(0).uniform(0.02, 0.9, (photos, side, side, 3)).round(4)
    return json.dumps({"inputs": values.tolist(), "params": {"refine": refine}}).encode()


def server_timing(header: str | None) -> dict[str, float]:
    """The stages of a ``Server-Timing`` header (``upload;dur=12, parse;dur=3``), in seconds."""
    stages = {}
    for part in (header or "").split(","):
        name, _, dur = part.strip().partition(";dur=")
        if dur:
            stages[name] = float(dur) / 1000
    return stages


def _post(url: str, body: bytes) -> tuple[int, str, dict[str, float], float]:
    """``(status, the answer's first line or "maps", its stages, seconds)`` of one POST."""
    kind = {"Content-Type": "application/json"}
    request = urllib.request.Request(url + "/invocations", data=body, headers=kind)
    start = time.perf_counter()
    try:
        with urllib.request.urlopen(request, timeout=900) as response:
            response.read()
            status, text, headers = response.status, "maps", response.headers
    except urllib.error.HTTPError as e:
        status, text, headers = e.code, e.read().decode(errors="replace").strip(), e.headers
    except OSError as e:
        status, text, headers = 0, f"{type(e).__name__}: {e}", {}
    return status, text, server_timing(headers.get("Server-Timing")), time.perf_counter() - start


def single_request(url: str, photos: int, side: int, refine: int, pid: int) -> dict:
    """One request of ``photos`` photos of ``side`` px at ``refine`` steps, alone: its status and
    answer, seconds, the worker's busy time and the server's peak memory (process ``pid``)."""
    body = _body(photos, side, refine)
    with MemorySampler(pid) as memory, PingProbe(url) as ping:
        status, text, stages, seconds = _post(url, body)
        # A small request next: how long it waits for the worker says how long this one still held it.
        held = _post(url, _body(1, 64, 0))[2].get("queue", 0.0)
    if "work" in stages:
        busy = stages["work"]
    else:  # answered (504) before its work ended, or refused before any
        started = sum(stages.get(k, 0.0) for k in ("upload", "parse", "queue"))
        busy = seconds - started + held if "queue" in stages else 0.0
    return {"body_mb": len(body) / 2**20, "status": status, "answer": text, "seconds": seconds,
            "stages": stages, "busy_s": busy, "server_mb": memory.server_mb,
            "tree_mb": memory.tree_mb, "ping_s": ping.worst_s}  # fmt: skip


def cases_table(rows: list[tuple[str, dict]]) -> str:
    """The figures of :func:`single_request` as a Markdown table, one row per case."""
    lines = ["| request | body MB | answer | s (the server's stages) | worker busy s | slowest /ping s "
             "| server peak RSS MB | with its children, PSS MB |",
             "| --- | ---: | --- | --- | ---: | ---: | ---: | ---: |"]  # fmt: skip
    for name, f in rows:
        answer = f"{f['status']} {f['answer'][:150]}".replace("|", "/")
        stages = ", ".join(f"{k} {v:.1f}" for k, v in f["stages"].items())
        lines.append(f"| {name} | {f['body_mb']:.0f} | {answer} | {f['seconds']:.1f} ({stages}) | "
                     f"{f['busy_s']:.1f} | {f['ping_s']:.2f} | {f['server_mb']:.0f} | {f['tree_mb']:.0f} |")
    return "\n".join(lines)


def _start_server(model: str, threads: int | None, options=()) -> tuple[subprocess.Popen, str]:
    """``svbrdf-models serve`` on a free loopback port (with ``options``), once it answers /ping."""
    port = _free_port()
    url = f"http://127.0.0.1:{port}"
    exe = os.path.join(os.path.dirname(sys.executable), "svbrdf-models")
    extra = (["--threads", str(threads)] if threads else []) + list(options)
    proc = subprocess.Popen([exe, "serve", model, "--port", str(port), *extra], stdout=subprocess.DEVNULL)
    for _ in range(600):
        try:
            urllib.request.urlopen(url + "/ping", timeout=2).read()
            break
        except OSError:
            time.sleep(0.2)
    return proc, url


def run_cases(model: str, names: list[str], threads: int | None, options: list[str] = ()) -> str:
    """Each case of :data:`CASES` named, on a fresh server (given ``options``, else the default
    limits): the table and the limits it ran under."""
    from svbrdf_models.modelfile.serve_limits import ServeLimits

    d = ServeLimits()
    rows = []
    for name in names:
        photos, side, refine, what = CASES[name]
        proc, url = _start_server(model, threads, options)
        try:
            rows.append((what, single_request(url, photos, side, refine, proc.pid)))
        finally:
            proc.terminate()
            proc.wait(30)
    limits = (f"default limits: --timeout {d.timeout:g} s (504 at {1.5 * d.timeout:g} s), --max-photos "
              f"{d.photos}, --max-pixels {d.pixels:,}, --max-body-mb {d.body_mb:g}, --max-answer-mb "
              f"{d.answer_mb:g}")  # fmt: skip
    return cases_table(rows) + "\n\n" + limits + (f"; this run: {' '.join(options)}" if options else "")


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
    parser.add_argument("--cases", help=f"instead, single requests, one server each: {','.join(CASES)}")
    parser.add_argument("--threads", type=int, help="the server's torch threads (default: its own choice)")
    parser.add_argument("--serve-options", default="", help="more options of the served model's, e.g. "
                        "'--max-answer-mb 1000' (default: none, the default limits)")  # fmt: skip
    args = parser.parse_args()
    if args.cases:
        print(run_cases(args.model, args.cases.split(","), args.threads, args.serve_options.split()))
        return
    proc, url = _start_server(args.model, args.threads)
    try:
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

"""Bounded load generator for the service (benchmarks/bench_service.py and the tests).

Loopback only: :func:`start_server` runs ``rulkit serve`` on 127.0.0.1 and a free port in a
subprocess; :func:`run_load` sends a fixed number of requests (``writers`` threads x
``batches`` POSTs of ``batch_size`` acquisitions, and ``readers`` threads issuing
``GET /api/v1/components?limit=50`` until the writers are done, at most ``max_reads`` each)
and stops by itself. :func:`verify_exactly_once` then checks the database holds every
acquisition exactly once.
"""

from __future__ import annotations

import http.client
import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rulkit.fleet.service.pgtemp import free_port


@dataclass
class Server:
    proc: subprocess.Popen
    port: int

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def cpu_seconds(self) -> float:
        """User + system CPU time the server process has used so far (Linux /proc)."""
        return _stat_cpu(f"/proc/{self.proc.pid}/stat")

    def loop_cpu_seconds(self) -> float:
        """The CPU time of the server's main thread so far: uvicorn's event loop (HTTP
        parsing, routing, the coroutines of the routes and their dependencies); the rest of
        :meth:`cpu_seconds` is the worker threads' (the routes' plain functions)."""
        return _stat_cpu(f"/proc/{self.proc.pid}/task/{self.proc.pid}/stat")

    def memory_mb(self) -> tuple[float, float]:
        """(resident, peak resident) memory of the server process, MB (Linux /proc)."""
        vals = {}
        with open(f"/proc/{self.proc.pid}/status") as f:
            for line in f:
                if line.startswith(("VmRSS:", "VmHWM:")):
                    vals[line.split(":")[0]] = int(line.split()[1]) / 1024.0
        return vals["VmRSS"], vals["VmHWM"]

    def kill(self) -> None:
        """``kill -9``: no shutdown handler runs."""
        if self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGKILL)
        self.proc.wait(30)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.kill()


def _stat_cpu(path: str) -> float:
    """User + system CPU seconds of a Linux ``/proc/.../stat`` file (a process or a thread)."""
    with open(path) as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def start_server(db: str, *, pool: int = 8, timeout: float = 60.0,
                 options: tuple[str, ...] = (), env: dict[str, str] | None = None) -> Server:
    """``rulkit serve --db DB [options]`` on 127.0.0.1 and a free port; waits for
    /readyz. ``env``: variables added to this process's environment for the server (e.g.
    ``PYTHONPATH`` of another checkout's ``src``, whose code then serves)."""
    port = free_port()
    cmd = [sys.executable, "-c", "from rulkit.cli import main; main()", "serve", "--db", str(db),
           "--port", str(port), "--pool", str(pool), *options]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env=None if env is None else {**os.environ, **env})
    srv = Server(proc, port)
    deadline = time.monotonic() + timeout
    while True:
        if proc.poll() is not None:
            err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
            raise RuntimeError(f"rulkit serve exited with {proc.returncode}: {err[-2000:]}")
        try:
            status, _ = request(srv.port, "GET", "/readyz", timeout=2)
            if status == 200:
                break
        except OSError:
            pass
        if time.monotonic() > deadline:
            srv.kill()
            raise RuntimeError("rulkit serve did not answer /readyz in time")
        time.sleep(0.1)
    # the server's log goes to a pipe nobody reads: drain it so the server never blocks
    threading.Thread(target=_drain, args=(proc,), daemon=True).start()
    return srv


def _drain(proc: subprocess.Popen) -> None:
    if proc.stderr is not None:
        for _ in proc.stderr:
            pass


def request(port: int, method: str, path: str, body: Any = None, token: str | None = None,
            conn: http.client.HTTPConnection | None = None, timeout: float = 60.0
            ) -> tuple[int, Any]:
    """One request (on ``conn`` if given, kept alive); returns (status, parsed JSON)."""
    c = conn or http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    headers = {"Content-Type": "application/json"}
    if token:
        headers["Authorization"] = f"Bearer {token}"
    data = None if body is None else json.dumps(body).encode()
    try:
        c.request(method, path, body=data, headers=headers)
        r = c.getresponse()
        raw = r.read()
    finally:
        if conn is None:
            c.close()
    return r.status, json.loads(raw) if raw else None


def writer_batch(writer: int, k: int, batch_size: int) -> list[dict[str, Any]]:
    """Batch ``k`` of writer ``writer``: one acquisition (time k) for each of its
    ``batch_size`` components, HI growing slowly with time."""
    hi = 0.2 + 0.002 * k + 0.0005 * np.arange(batch_size)
    return [{"component": f"w{writer}-c{i}", "time": float(k), "hi": float(hi[i])}
            for i in range(batch_size)]


@dataclass
class LoadResult:
    writers: int
    readers: int
    batches: int
    batch_size: int
    seconds: float
    post_latency: list[float] = field(default_factory=list)
    get_latency: list[float] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    duplicates: int = 0

    @property
    def acquisitions(self) -> int:
        return self.writers * self.batches * self.batch_size

    @property
    def rate(self) -> float:
        return self.acquisitions / self.seconds

    def summary(self) -> dict[str, float]:
        def q(v: list[float], p: float) -> float:
            return float(np.percentile(v, p)) * 1e3 if v else float("nan")

        return {"acquisitions": self.acquisitions, "seconds": self.seconds,
                "acq_per_s": self.rate, "post_p50_ms": q(self.post_latency, 50),
                "post_p99_ms": q(self.post_latency, 99), "get_p50_ms": q(self.get_latency, 50),
                "get_p99_ms": q(self.get_latency, 99), "gets": len(self.get_latency),
                "errors": len(self.errors)}


def run_load(port: int, token: str, *, writers: int = 8, readers: int = 8, batches: int = 50,
             batch_size: int = 100, max_reads: int = 10_000, first_batch: int = 0) -> LoadResult:
    """``writers`` x ``batches`` POSTs, with ``readers`` polling the worst-50 list meanwhile."""
    res = LoadResult(writers, readers, batches, batch_size, 0.0)
    lock = threading.Lock()
    done = threading.Event()
    bodies = {(w, k): {"rows": writer_batch(w, k, batch_size)}
              for w in range(writers) for k in range(first_batch, first_batch + batches)}

    def write(w: int) -> None:
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=120)
        try:
            for k in range(first_batch, first_batch + batches):
                t0 = time.perf_counter()
                status, body = request(port, "POST", "/api/v1/acquisitions", bodies[(w, k)],
                                       token, conn)
                dt = time.perf_counter() - t0
                with lock:
                    res.post_latency.append(dt)
                    if status != 200:
                        res.errors.append(f"POST {status}: {str(body)[:200]}")
                    else:
                        res.duplicates += int(body["duplicates"])
        except OSError as err:
            with lock:
                res.errors.append(f"writer {w}: {err!r}")
        finally:
            conn.close()

    def read() -> None:
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=120)
        try:
            for _ in range(max_reads):
                if done.is_set():
                    break
                t0 = time.perf_counter()
                status, body = request(port, "GET", "/api/v1/components?limit=50", None, token,
                                       conn)
                dt = time.perf_counter() - t0
                with lock:
                    res.get_latency.append(dt)
                    if status != 200:
                        res.errors.append(f"GET {status}: {str(body)[:200]}")
        except OSError as err:
            with lock:
                res.errors.append(f"reader: {err!r}")
        finally:
            conn.close()

    ws = [threading.Thread(target=write, args=(w,)) for w in range(writers)]
    rs = [threading.Thread(target=read) for _ in range(readers)]
    t0 = time.perf_counter()
    for t in ws + rs:
        t.start()
    for t in ws:
        t.join()
    res.seconds = time.perf_counter() - t0
    done.set()
    for t in rs:
        t.join()
    return res


def verify_exactly_once(db: str, writers: int, batches: int, batch_size: int,
                        first_batch: int = 0) -> None:
    """Every acquisition of :func:`run_load` stored exactly once (AssertionError if not)."""
    from rulkit.fleet.store.postgres import open_store

    with open_store(db, create=False) as store:
        hist = store.history()
        status = store.status()
    ours = hist[hist["component"].str.match(r"^w\d+-c\d+$")]
    expected = writers * batches * batch_size
    assert len(ours) == expected, f"{len(ours)} history rows, expected {expected}"
    assert not ours.duplicated(["component", "t"]).any(), "duplicated acquisitions"
    want = {(f"w{w}-c{i}", float(k)) for w in range(writers) for i in range(batch_size)
            for k in range(first_batch, first_batch + batches)}
    got = set(zip(ours["component"], ours["t"].astype(float), strict=True))
    assert got == want, f"{len(want - got)} missing, {len(got - want)} unexpected"
    n = status.set_index("component")["n"]
    counts = ours.groupby("component").size()
    assert (n.loc[counts.index] == counts).all(), "component counts disagree with history"

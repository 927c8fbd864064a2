"""Bounded load generator for the service (benchmarks/bench_service.py and the tests).

Loopback only: :func:`start_server` runs ``rulkit serve`` on 127.0.0.1 and a free port in a
subprocess; :func:`run_load` sends a fixed number of requests (``writers`` threads x
``batches`` POSTs of ``batch_size`` acquisitions, and ``readers`` threads issuing
``GET /api/v1/components?limit=50`` until the writers are done, at most ``max_reads`` each)
and stops by itself. :func:`verify_exactly_once` then checks the database holds every
acquisition exactly once.

The client shares the machine with the server it measures, so it costs as little as it can:
every request's bytes (request line, headers, JSON body) are built before the clock starts,
each thread keeps one connection (:class:`Exchange`: a bare HTTP/1.1 exchange over a socket,
responses framed by their ``Content-Length``), and only the writers' responses are parsed
(the duplicates they report; orjson).
"""

from __future__ import annotations

import http.client
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import orjson

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


def raw_request(method: str, path: str, token: str | None = None, body: bytes = b"") -> bytes:
    """The bytes of one HTTP/1.1 request on a kept-alive connection (a JSON body with
    ``POST``)."""
    head = [f"{method} {path} HTTP/1.1", "Host: 127.0.0.1"]
    if token is not None:
        head.append(f"Authorization: Bearer {token}")
    if method == "POST":
        head += ["Content-Type: application/json", f"Content-Length: {len(body)}"]
    return ("\r\n".join(head) + "\r\n\r\n").encode() + body


class Exchange:
    """One kept-alive connection to the server on 127.0.0.1 and ``port``: :meth:`send`
    writes a request's bytes (:func:`raw_request`) and reads its response, framed by its
    ``Content-Length`` (every response of the service has one)."""

    def __init__(self, port: int, timeout: float = 120.0) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=timeout)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.buf = bytearray()

    def send(self, data: bytes) -> tuple[int, bytes]:
        """(status, body) of the response to ``data``."""
        self.sock.sendall(data)
        while True:
            end = self.buf.find(b"\r\n\r\n")
            if end >= 0:
                length = _content_length(bytes(self.buf[:end]))
                if len(self.buf) >= end + 4 + length:
                    status = int(self.buf[9:12])
                    body = bytes(self.buf[end + 4:end + 4 + length])
                    del self.buf[:end + 4 + length]
                    return status, body
            chunk = self.sock.recv(1 << 16)
            if not chunk:
                raise ConnectionError("the server closed the connection")
            self.buf += chunk

    def close(self) -> None:
        self.sock.close()


def _content_length(head: bytes) -> int:
    """The ``Content-Length`` of a response's header block (0 without one; a chunked
    response is refused: the service sends none)."""
    length = 0
    for line in head.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        name = name.strip().lower()
        if name == b"content-length":
            length = int(value)
        elif name == b"transfer-encoding":
            raise ConnectionError("a chunked response: this client reads Content-Length only")
    return length


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
    """``writers`` x ``batches`` POSTs, with ``readers`` polling the worst-50 list meanwhile
    (every request's bytes built before the clock starts)."""
    res = LoadResult(writers, readers, batches, batch_size, 0.0)
    lock = threading.Lock()
    done = threading.Event()
    ks = range(first_batch, first_batch + batches)
    posts = {w: [raw_request("POST", "/api/v1/acquisitions", token, json.dumps(
        {"rows": writer_batch(w, k, batch_size)}).encode()) for k in ks]
        for w in range(writers)}
    poll = raw_request("GET", "/api/v1/components?limit=50", token)

    def write(w: int) -> None:
        lat, dup, errors = [], 0, []
        try:
            conn = Exchange(port)
            try:
                for data in posts[w]:
                    t0 = time.perf_counter()
                    status, raw = conn.send(data)
                    lat.append(time.perf_counter() - t0)
                    if status != 200:
                        errors.append(f"POST {status}: {raw[:200]!r}")
                    else:
                        dup += int(orjson.loads(raw)["duplicates"])
            finally:
                conn.close()
        except OSError as err:
            errors.append(f"writer {w}: {err!r}")
        with lock:
            res.post_latency += lat
            res.duplicates += dup
            res.errors += errors

    def read() -> None:
        lat, errors = [], []
        try:
            conn = Exchange(port)
            try:
                for _ in range(max_reads):
                    if done.is_set():
                        break
                    t0 = time.perf_counter()
                    status, raw = conn.send(poll)
                    lat.append(time.perf_counter() - t0)
                    if status != 200:
                        errors.append(f"GET {status}: {raw[:200]!r}")
            finally:
                conn.close()
        except OSError as err:
            errors.append(f"reader: {err!r}")
        with lock:
            res.get_latency += lat
            res.errors += errors

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

"""A throwaway PostgreSQL server in a temporary directory (tests and benchmarks).

Uses the server binaries of an installed PostgreSQL (Debian: ``/usr/lib/postgresql/*/bin``):
``initdb`` into a fresh directory, ``pg_ctl start`` on a free loopback port with trust
authentication for the local user ``rulkit``, and ``pg_ctl stop -m immediate`` plus removal of
the directory at the end. PostgreSQL refuses to run as root, so as root the binaries run as the
``postgres`` user (or ``nobody``) through ``runuser``, on a directory chowned to that user.
Durability is off by default (``fsync=off``, ``synchronous_commit=off``): the tests' data is
thrown away anyway. ``TempPostgres(durable=True)`` keeps PostgreSQL's durable defaults (a commit
returns after its write-ahead log is flushed), as a benchmark of the service must: the SQLite
store it is compared with syncs every commit.
"""

from __future__ import annotations

import glob
import os
import shutil
import socket
import subprocess
import tempfile
from pathlib import Path


def find_pg_bin() -> Path | None:
    """Directory holding ``initdb`` and ``pg_ctl`` (newest version), or None."""
    env = os.environ.get("RULKIT_PG_BIN")
    if env:
        return Path(env)
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"),
                   key=lambda p: int(Path(p).parent.parent.name)
                   if Path(p).parent.parent.name.isdigit() else 0)
    if found:
        return Path(found[-1]).parent
    initdb = shutil.which("initdb")
    return Path(initdb).resolve().parent if initdb else None


def unavailable_reason() -> str | None:
    """Why a throwaway server cannot be started here, or None if it can."""
    bindir = find_pg_bin()
    if bindir is None or not (bindir / "pg_ctl").exists():
        return "PostgreSQL server binaries (initdb, pg_ctl) not found: apt-get install postgresql"
    if os.geteuid() == 0 and _run_as_user() is None:
        return "running as root and no 'postgres' or 'nobody' user to run PostgreSQL as"
    try:
        import psycopg  # noqa: F401
    except ImportError:
        return "psycopg is not installed: pip install 'rulkit[service]'"
    return None


def _run_as_user() -> str | None:
    import pwd

    for name in ("postgres", "nobody"):
        try:
            pwd.getpwnam(name)
            return name
        except KeyError:
            continue
    return None


def _proc_ticks(pid: int, *, parent: int | None = None, reaped: bool = False
                ) -> tuple[int, ...]:
    """A process's user and system clock ticks from ``/proc/PID/stat`` (with ``reaped``,
    also those of its children it has waited for); ``()`` when it has exited or its parent is
    not ``parent``."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return ()
    if parent is not None and int(fields[1]) != parent:
        return ()
    return tuple(int(v) for v in fields[11:15 if reaped else 13])


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class TempPostgres:
    """``with TempPostgres() as pg: url = pg.create_database("t1")``; ``durable``: the
    server's durable defaults instead of ``fsync=off`` (module docstring)."""

    def __init__(self, *, durable: bool = False) -> None:
        self.durable = durable
        bindir = find_pg_bin()
        if bindir is None:
            raise RuntimeError(unavailable_reason() or "PostgreSQL not found")
        self.bindir = bindir
        self.dir = Path(tempfile.mkdtemp(prefix="rulkit-pg-"))
        self.port = free_port()
        self.user = _run_as_user() if os.geteuid() == 0 else None
        self._n = 0
        self._started = False

    def _cmd(self, *args: str) -> list[str]:
        cmd = list(args)
        return ["runuser", "-u", self.user, "--", *cmd] if self.user else cmd

    def start(self) -> TempPostgres:
        if self.user:
            import pwd

            pw = pwd.getpwnam(self.user)
            os.chown(self.dir, pw.pw_uid, pw.pw_gid)
        data = self.dir / "data"
        subprocess.run(self._cmd(str(self.bindir / "initdb"), "-D", str(data), "-U", "rulkit",
                                 "--auth=trust", "-E", "UTF8", "--no-locale", "--no-sync"),
                       check=True, capture_output=True, timeout=120)
        opts = f"-p {self.port} -k {self.dir} -c listen_addresses=127.0.0.1 -c max_connections=100"
        if not self.durable:
            opts += " -c fsync=off -c synchronous_commit=off -c full_page_writes=off"
        subprocess.run(self._cmd(str(self.bindir / "pg_ctl"), "-D", str(data), "-o", opts, "-w",
                                 "-t", "60", "-l", str(self.dir / "log"), "start"),
                       check=True, capture_output=True, timeout=90)
        self._started = True
        return self

    def url(self, dbname: str = "postgres") -> str:
        return f"postgresql://rulkit@127.0.0.1:{self.port}/{dbname}"

    def create_database(self, name: str | None = None) -> str:
        """A new empty database; returns its URL."""
        import psycopg

        if name is None:
            self._n += 1
            name = f"t{self._n}"
        with psycopg.connect(self.url(), autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{name}" STRATEGY FILE_COPY')
        return self.url(name)

    def create_schema(self, name: str | None = None) -> str:
        """A new empty schema in the ``postgres`` database; returns a URL whose
        ``search_path`` is that schema (much cheaper than a database per test)."""
        import psycopg

        if name is None:
            self._n += 1
            name = f"s{self._n}"
        with psycopg.connect(self.url(), autocommit=True) as conn:
            conn.execute(f'CREATE SCHEMA "{name}"')
        return f"{self.url()}?options=-csearch_path%3D{name}"

    def cpu_seconds(self) -> float:
        """User + system CPU seconds the server's processes have used so far (Linux /proc):
        the postmaster's own, its live children's (the connections' backends, the WAL writer,
        the checkpointer, autovacuum) and those of the children it has reaped (a closed
        connection's backend), so that the difference over a load is the server's CPU for it."""
        with open(self.dir / "data" / "postmaster.pid") as f:
            pid = int(f.readline())
        total = sum(_proc_ticks(pid, reaped=True))
        for entry in os.scandir("/proc"):
            if entry.name.isdigit() and entry.name != str(pid):
                ticks = _proc_ticks(int(entry.name), parent=pid)
                total += sum(ticks)
        return total / os.sysconf("SC_CLK_TCK")

    def stop(self) -> None:
        if self._started:
            subprocess.run(self._cmd(str(self.bindir / "pg_ctl"), "-D", str(self.dir / "data"),
                                     "-m", "immediate", "-w", "stop"),
                           capture_output=True, timeout=60)
            self._started = False
        shutil.rmtree(self.dir, ignore_errors=True)

    def __enter__(self) -> TempPostgres:
        try:
            return self.start()
        except BaseException:
            self.stop()
            raise

    def __exit__(self, *exc: object) -> None:
        self.stop()

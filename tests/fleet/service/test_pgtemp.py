"""The throwaway PostgreSQL server of the tests and benchmarks (rulkit.fleet.service.pgtemp)."""

import os
import time


def _ticks(pid):
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def test_cpu_seconds_counts_a_backend_also_after_its_connection_closed(pg_server):
    """The server's CPU over a load includes a connection's backend, whose own /proc figure
    (the oracle) is gone once it exits and the postmaster reaps it."""
    import psycopg

    before = pg_server.cpu_seconds()
    with psycopg.connect(pg_server.url()) as conn:
        pid = conn.execute("SELECT pg_backend_pid()").fetchone()[0]
        conn.execute("SELECT count(*) FROM generate_series(1, 3000000)").fetchone()
        own = _ticks(pid)
    for _ in range(1000):  # the backend exits and the postmaster reaps it
        if not os.path.exists(f"/proc/{pid}"):
            break
        time.sleep(0.01)
    assert not os.path.exists(f"/proc/{pid}")
    assert own > 0.05
    assert pg_server.cpu_seconds() - before >= own - 1e-9

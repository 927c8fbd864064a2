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


def _settings(url):
    import psycopg

    with psycopg.connect(url) as conn:
        return {k: conn.execute(f"SHOW {k}").fetchone()[0]
                for k in ("fsync", "synchronous_commit", "full_page_writes")}


def test_the_tests_server_trades_durability_for_speed(pg_server):
    assert _settings(pg_server.url()) == {"fsync": "off", "synchronous_commit": "off",
                                          "full_page_writes": "off"}


def test_a_durable_server_keeps_postgresqls_durable_defaults(need):
    """What bench_service.py measures: a commit returns after its WAL is flushed."""
    from rulkit.fleet.service.pgtemp import TempPostgres, unavailable_reason

    need(unavailable_reason())
    with TempPostgres(durable=True) as pg:
        assert _settings(pg.url()) == {"fsync": "on", "synchronous_commit": "on",
                                       "full_page_writes": "on"}

"""Fixtures of the fleet tests: both store backends (SQLite file, throwaway PostgreSQL).

PostgreSQL tests start a throwaway server (rulkit.fleet.service.pgtemp) once per session.
Without PostgreSQL those tests skip with the reason, unless RULKIT_REQUIRE_INTEGRATION=1 (set by
.ci/run), which turns the skip into a failure.
"""

import os

import pytest

from rulkit.fleet.service.pgtemp import TempPostgres, unavailable_reason

REQUIRE = os.environ.get("RULKIT_REQUIRE_INTEGRATION", "") not in ("", "0")


def _need(reason: str | None) -> None:
    """Skip (or fail under RULKIT_REQUIRE_INTEGRATION=1) when ``reason`` is set."""
    if reason:
        if REQUIRE:
            pytest.fail(f"{reason} (RULKIT_REQUIRE_INTEGRATION=1)")
        pytest.skip(reason)


@pytest.fixture(scope="session")
def pg_server():
    _need(unavailable_reason())
    with TempPostgres() as pg:
        yield pg


@pytest.fixture(params=["sqlite", "postgresql"])
def db_url(request, tmp_path):
    """A fresh, empty database of each backend (SQLite path or PostgreSQL URL)."""
    if request.param == "sqlite":
        return str(tmp_path / "fleet.db")
    pg = request.getfixturevalue("pg_server")
    return pg.create_schema()


@pytest.fixture(name="need")
def need_fixture():
    """``need(reason)``: skip, or fail under RULKIT_REQUIRE_INTEGRATION=1."""
    return _need

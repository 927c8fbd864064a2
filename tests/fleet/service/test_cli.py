"""`rulkit token create|revoke|list` and `rulkit serve` wiring."""

import sqlite3

from typer.testing import CliRunner

from rulkit.cli import app
from rulkit.fleet.service.db import ServiceDB, hash_token


def test_token_create_prints_once_stores_hash_and_revokes(tmp_path):
    db = str(tmp_path / "fleet.db")
    runner = CliRunner()
    r = runner.invoke(app, ["token", "create", "--db", db, "--role", "write", "--name", "ops"])
    assert r.exit_code == 0, r.output
    token = r.stdout.strip().splitlines()[-1]
    assert token.startswith("rk_") and len(token) > 40
    con = sqlite3.connect(db)
    rows = con.execute("SELECT name, role, hash FROM api_tokens").fetchall()
    con.close()
    assert rows == [("ops", "write", hash_token(token))]
    sdb = ServiceDB(db)
    assert sdb.check_token(token).role == "write"
    r = runner.invoke(app, ["token", "list", "--db", db])
    assert r.exit_code == 0 and "ops" in r.stdout and token not in r.stdout
    r = runner.invoke(app, ["token", "revoke", "--db", db, "--name", "ops"])
    assert r.exit_code == 0 and "revoked 1" in r.stdout
    assert sdb.check_token(token) is None
    r = runner.invoke(app, ["token", "revoke", "--db", db, "--name", "ops"])
    assert r.exit_code == 1 and "no active token" in r.output
    r = runner.invoke(app, ["token", "create", "--db", db, "--role", "admin"])
    assert r.exit_code == 1 and "read or write" in r.output
    r = runner.invoke(app, ["token", "revoke", "--db", str(tmp_path / "missing.db"),
                            "--id", "1"])
    assert r.exit_code == 1 and "missing.db" in r.output
    assert not (tmp_path / "missing.db").exists()
    sdb.close()


def test_serve_help_lists_options():
    r = CliRunner().invoke(app, ["serve", "--help"])
    assert r.exit_code == 0
    for opt in ("--db", "--host", "--port"):
        assert opt in r.stdout


def test_unreachable_postgres_is_a_message_without_the_password():
    from rulkit.fleet.store.postgres import _redact

    assert _redact("postgresql://ops:s3cret@db.local:5432/fleet") == (
        "postgresql://ops:***@db.local:5432/fleet")
    r = CliRunner().invoke(app, ["token", "create", "--db",
                                 "postgresql://ops:s3cret@127.0.0.1:1/fleet", "--role", "read"])
    assert r.exit_code == 1 and "cannot connect to PostgreSQL" in r.output, r.output
    assert "s3cret" not in r.output

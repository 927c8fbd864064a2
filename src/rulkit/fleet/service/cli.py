"""``rulkit serve`` and ``rulkit token create|revoke|list`` (docs/service.md).

Heavy imports (FastAPI, uvicorn, psycopg) stay inside the commands.
"""

from __future__ import annotations

from typing import Annotated

import typer

DB_HELP = "Component database: a SQLite path (created if new) or a postgresql:// URL."


def _fail(msg: str, code: int = 1) -> None:
    typer.echo(f"error: {msg}", err=True)
    raise typer.Exit(code=code)


def _open(db: str, create: bool = True):
    try:
        from rulkit.fleet.service.db import ServiceDB
    except ImportError as err:
        _fail(f"the service needs its extra: pip install 'rulkit[service]' ({err})")
    try:
        return ServiceDB(db, pool_size=1, create=create)
    except (ValueError, FileNotFoundError, ConnectionError, RuntimeError) as err:
        _fail(str(err), getattr(err, "exit_code", 1))
    raise AssertionError  # unreachable


def register(app: typer.Typer, reproduce: typer.Typer) -> None:
    """Add ``serve`` and the ``token`` group."""
    token = typer.Typer(help="API tokens of the fleet service (only their hash is stored).",
                        no_args_is_help=True)
    app.add_typer(token, name="token")

    @app.command("serve")
    def serve(
        db: Annotated[str, typer.Option("--db", help=DB_HELP)],
        host: Annotated[str, typer.Option("--host", help="Address to bind.")] = "127.0.0.1",
        port: Annotated[int, typer.Option("--port", min=0, max=65535)] = 8000,
        pool: Annotated[int, typer.Option("--pool", min=1, max=64,
                                          help="Database connections.")] = 8,
        log_format: Annotated[str, typer.Option(
            "--log-format", help="text or json (one JSON object per line).")] = "text",
        header_timeout: Annotated[float, typer.Option(
            "--header-timeout", min=0.1, max=3600,
            help="Seconds a client has to send a request's headers.")] = 10.0,
        grace: Annotated[float, typer.Option(
            "--grace", min=0, max=3600,
            help="On SIGTERM/SIGINT, seconds the requests in flight get to finish.")] = 30.0,
    ) -> None:
        """HTTP API (/api/v1, /openapi.json, /healthz, /readyz, /metrics) and dashboard (/)
        over the database."""
        if log_format not in ("text", "json"):
            _fail(f"--log-format: expected text or json, got {log_format!r}", 2)
        try:
            from rulkit.fleet.service.app import create_app
            from rulkit.fleet.service.server import serve as run
            from rulkit.fleet.service.server import setup_logging
        except ImportError as err:
            _fail(f"the service needs its extra: pip install 'rulkit[service]' ({err})")
        sdb = _open(db)
        sdb.pool_size = pool
        setup_logging(log_format)
        api = create_app(sdb)
        typer.echo(f"rulkit service on http://{host}:{port}/ ({sdb.dialect})", err=True)
        try:
            run(api, host, port, header_timeout=header_timeout, grace=grace)
        finally:
            sdb.close()

    @token.command("create")
    def token_create(
        db: Annotated[str, typer.Option("--db", help=DB_HELP)],
        role: Annotated[str, typer.Option("--role", help="read or write.")],
        name: Annotated[str, typer.Option("--name", help="Who or what uses it.")] = "token",
    ) -> None:
        """Create a token and print it once (it cannot be shown again)."""
        if role not in ("read", "write"):
            _fail(f"--role: expected read or write, got {role!r}")
        sdb = _open(db)
        try:
            tid, tok = sdb.create_token(role, name)
        finally:
            sdb.close()
        typer.echo(f"created {role} token id {tid} (store it now, it is not shown again):",
                   err=True)
        typer.echo(tok)

    @token.command("revoke")
    def token_revoke(
        db: Annotated[str, typer.Option("--db", help=DB_HELP)],
        token_id: Annotated[int | None, typer.Option("--id", help="Token id.")] = None,
        name: Annotated[str | None, typer.Option("--name",
                                                 help="Revoke every token of this name.")] = None,
    ) -> None:
        """Revoke a token by id or every active token of a name."""
        if (token_id is None) == (name is None):
            _fail("give --id or --name")
        sdb = _open(db, create=False)
        try:
            n = sdb.revoke_token(token_id=token_id, name=name)
        finally:
            sdb.close()
        if n == 0:
            _fail("no active token matched")
        typer.echo(f"revoked {n} token(s)")

    @token.command("list")
    def token_list(db: Annotated[str, typer.Option("--db", help=DB_HELP)]) -> None:
        """Tokens: id, name, role, created, revoked (never the token)."""
        import datetime as dt

        sdb = _open(db, create=False)
        try:
            rows = sdb.list_tokens()
        finally:
            sdb.close()

        def iso(t: float | None) -> str:
            return "-" if t is None else dt.datetime.fromtimestamp(t, dt.UTC).isoformat(
                timespec="seconds")

        for r in rows:
            name = r["name"].encode("unicode_escape").decode("ascii")
            typer.echo(f"{r['id']}\t{r['role']}\t{name}\tcreated {iso(r['created'])}\t"
                       f"revoked {iso(r['revoked'])}")

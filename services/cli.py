"""Service sub-commands of ``firefly3d``: ``admin`` (teams, tokens), ``serve``, ``worker``.

Registered through the ``firefly3d.commands`` entry point, so the science package's
CLI never imports service code.
"""

from __future__ import annotations

import argparse
import sys
import uuid
from collections.abc import Callable
from typing import TYPE_CHECKING

from services.core.settings import get_settings

if TYPE_CHECKING:
    from sqlalchemy.orm import Session

    from services.core.models import Team
    from services.domain.teams import Issued


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``admin``, ``serve`` and ``worker``."""
    admin = subparsers.add_parser("admin", help="administer the service (teams and tokens)")
    commands = admin.add_subparsers(dest="admin_command", metavar="COMMAND", required=True)
    create = commands.add_parser(
        "create-team", help="create a team and print its API token (shown only once)"
    )
    create.add_argument("name", help="team name (unique)")
    _expiry_option(create)
    create.set_defaults(func=_create_team)
    listing = commands.add_parser("list-tokens", help="every team's tokens (never the secrets)")
    listing.set_defaults(func=_list_tokens)
    issue = commands.add_parser("issue-token", help="print a further token for a team")
    issue.add_argument("team", help="team name")
    issue.add_argument("--label", default="", help="what the token is for")
    _expiry_option(issue)
    issue.set_defaults(func=_issue_token)
    revoke = commands.add_parser("revoke-token", help="revoke a token by its ID")
    revoke.add_argument("token_id", help="token ID (from list-tokens)")
    revoke.set_defaults(func=_revoke_token)
    rotate = commands.add_parser(
        "rotate-token", help="revoke every token of a team and print a new one"
    )
    rotate.add_argument("team", help="team name")
    _expiry_option(rotate)
    rotate.set_defaults(func=_rotate_token)

    serve = subparsers.add_parser("serve", help="run the web API (uvicorn)")
    serve.add_argument("--host", default="127.0.0.1")
    serve.add_argument("--port", type=int, default=8000)
    serve.add_argument("--workers", type=int, help="API processes (default: FIREFLY3D_API_WORKERS)")
    serve.set_defaults(func=_serve)

    worker = subparsers.add_parser("worker", help="run a Celery worker for the pipeline stages")
    worker.add_argument("--concurrency", type=int, help="processes (default: CPU count)")
    worker.add_argument("--queues", help="comma-separated queues (default: FIREFLY3D_QUEUE)")
    worker.add_argument("--loglevel", default="INFO")
    worker.add_argument("--hostname", help="node name, e.g. worker1@%%h")
    worker.set_defaults(func=_worker)


def _expiry_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--expires-in-days", type=float, help="the token stops working after this (default: never)"
    )


def _admin(action: Callable[[Session], int]) -> int:
    """Run `action` in a session; a domain error is one line on stderr, status 1."""
    from services.core.db import make_engine, make_session_factory
    from services.domain.errors import DomainError

    engine = make_engine(get_settings().database_url)
    try:
        with make_session_factory(engine)() as session:
            return action(session)
    except DomainError as exc:
        print(f"error: {exc.message}", file=sys.stderr)
        return 1
    finally:
        engine.dispose()


def _print_issued(issued: Issued) -> int:
    print(issued.secret)
    expiry = (
        f", expires {issued.token.expires_at:%Y-%m-%d %H:%M} UTC" if issued.token.expires_at else ""
    )
    print(
        f"token {issued.token.id} of team {issued.team.name!r}{expiry}; keep it: it is not "
        "stored and cannot be shown again",
        file=sys.stderr,
    )
    return 0


def _team_named(session: Session, name: str) -> Team:
    from services.domain.errors import NotFound
    from services.domain.repositories import teams

    team = teams.by_name(session, name)
    if team is None:
        raise NotFound(f"no team named {name!r}")
    return team


def _create_team(args: argparse.Namespace) -> int:
    from services.domain import teams

    return _admin(lambda s: _print_issued(teams.create_team(s, args.name, args.expires_in_days)))


def _issue_token(args: argparse.Namespace) -> int:
    from services.domain import teams

    return _admin(
        lambda s: _print_issued(
            teams.issue_token(s, _team_named(s, args.team), args.label, args.expires_in_days)
        )
    )


def _rotate_token(args: argparse.Namespace) -> int:
    from services.domain import teams

    return _admin(
        lambda s: _print_issued(
            teams.rotate(s, _team_named(s, args.team), expires_in_days=args.expires_in_days)
        )
    )


def _list_tokens(args: argparse.Namespace) -> int:
    from services.domain import teams

    def show(session: Session) -> int:
        for team in teams.list_teams(session):
            for token in team.tokens:
                print(
                    f"{token.id}  {team.name}  {token.label or '-'}  "
                    f"created {token.created_at:%Y-%m-%d}  {teams.token_state(token)}"
                )
        return 0

    return _admin(show)


def _revoke_token(args: argparse.Namespace) -> int:
    from services.domain import teams
    from services.domain.errors import Invalid

    def revoke(session: Session) -> int:
        try:
            token_id = uuid.UUID(args.token_id)
        except ValueError:
            raise Invalid(["token_id"], f"{args.token_id!r} is not a token ID") from None
        token = teams.revoke_token(session, token_id)
        print(f"token {token.id} of team {token.team.name!r} revoked", file=sys.stderr)
        return 0

    return _admin(revoke)


def _serve(args: argparse.Namespace) -> int:
    import uvicorn

    uvicorn.run(
        "services.api.app:create_app",
        factory=True,
        host=args.host,
        port=args.port,
        workers=args.workers or get_settings().api_workers,
    )
    return 0


def _worker(args: argparse.Namespace) -> int:
    from services.worker.tasks import app

    argv = ["worker", f"--loglevel={args.loglevel}"]
    argv.append(f"--queues={args.queues or get_settings().queue}")
    if args.concurrency:
        argv.append(f"--concurrency={args.concurrency}")
    if args.hostname:
        argv.append(f"--hostname={args.hostname}")
    app.worker_main(argv)
    return 0

"""Service sub-commands of ``firefly3d``: ``admin create-team``, ``serve``, ``worker``.

Registered through the ``firefly3d.commands`` entry point, so the science package's
CLI never imports service code.
"""

from __future__ import annotations

import argparse
import sys

from services.core.settings import get_settings


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``admin``, ``serve`` and ``worker``."""
    admin = subparsers.add_parser("admin", help="administer the service (teams)")
    admin_commands = admin.add_subparsers(dest="admin_command", metavar="COMMAND", required=True)
    create = admin_commands.add_parser(
        "create-team", help="create a team and print its API token (shown only once)"
    )
    create.add_argument("name", help="team name (unique)")
    create.set_defaults(func=_create_team)

    serve = subparsers.add_parser("serve", help="run the web API (uvicorn)")
    serve.add_argument("--host", default="127.0.0.1")
    serve.add_argument("--port", type=int, default=8000)
    serve.add_argument("--workers", type=int, default=1, help="API processes")
    serve.set_defaults(func=_serve)

    worker = subparsers.add_parser("worker", help="run a Celery worker for the pipeline stages")
    worker.add_argument("--concurrency", type=int, help="processes (default: CPU count)")
    worker.add_argument("--queues", help="comma-separated queues (default: FIREFLY3D_QUEUE)")
    worker.add_argument("--loglevel", default="INFO")
    worker.add_argument("--hostname", help="node name, e.g. worker1@%%h")
    worker.set_defaults(func=_worker)


def _create_team(args: argparse.Namespace) -> int:
    from sqlalchemy.exc import IntegrityError

    from services.core.db import make_engine, make_session_factory, transaction
    from services.core.models import Team
    from services.core.security import hash_token, new_team_token
    from services.domain.repositories import teams

    name = args.name.strip()
    if not name or len(name) > 100:
        print("error: a team name has 1 to 100 characters", file=sys.stderr)
        return 2
    token = new_team_token()
    engine = make_engine(get_settings().database_url)
    try:
        with transaction(make_session_factory(engine)) as session:
            if teams.by_name(session, name) is not None:
                print(f"error: team {name!r} already exists", file=sys.stderr)
                return 1
            session.add(Team(name=name, token_hash=hash_token(token)))
    except IntegrityError:
        print(f"error: team {name!r} already exists", file=sys.stderr)
        return 1
    finally:
        engine.dispose()
    print(token)
    print(
        f"team {name!r} created; keep this token: it is not stored and cannot be shown again",
        file=sys.stderr,
    )
    return 0


def _serve(args: argparse.Namespace) -> int:
    import uvicorn

    uvicorn.run(
        "services.api.app:create_app",
        factory=True,
        host=args.host,
        port=args.port,
        workers=args.workers,
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

"""Database engine and sessions (SQLAlchemy 2, psycopg 3)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from sqlalchemy import Engine, create_engine
from sqlalchemy.orm import Session, sessionmaker

SessionFactory = sessionmaker[Session]


def make_engine(url: str, *, pool_size: int = 5, pre_ping: bool = True) -> Engine:
    """An engine; `pre_ping` checks each connection before use (workers hold connections
    across long tasks, while the API, whose requests are short, skips that round trip)."""
    return create_engine(url, pool_pre_ping=pre_ping, pool_size=pool_size, max_overflow=10)


def make_session_factory(engine: Engine) -> SessionFactory:
    """Sessions whose objects stay readable after commit (they are returned to callers)."""
    return sessionmaker(engine, expire_on_commit=False)


@contextmanager
def transaction(sessions: SessionFactory) -> Iterator[Session]:
    """A session inside one transaction: committed on success, rolled back on error."""
    with sessions() as session, session.begin():
        yield session

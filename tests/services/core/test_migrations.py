"""Alembic migrations build exactly the ORM models' schema, and undo it."""

from __future__ import annotations

from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import create_engine, inspect

from services.core.models import Base
from tests.services.conftest import alembic_config, create_database, drop_database


def test_upgrade_head_matches_models_and_downgrade_removes_all() -> None:
    url = create_database("firefly3d_migrations")
    engine = create_engine(url)
    try:
        config = alembic_config(url)
        command.upgrade(config, "head")
        with engine.connect() as connection:
            diff = compare_metadata(
                MigrationContext.configure(connection, opts={"compare_type": True}), Base.metadata
            )
        assert diff == []
        assert set(inspect(engine).get_table_names()) == set(Base.metadata.tables) | {
            "alembic_version"
        }

        command.downgrade(config, "base")
        assert inspect(engine).get_table_names() == ["alembic_version"]
    finally:
        engine.dispose()
        drop_database(url)

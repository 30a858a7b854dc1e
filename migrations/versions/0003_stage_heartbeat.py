"""stage heartbeat: running stages write a sign of life; the sweeper re-queues silent ones

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-28
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.add_column("stages", sa.Column("heartbeat_at", sa.DateTime(timezone=True), nullable=True))
    op.add_column("stages", sa.Column("stalled_at", sa.DateTime(timezone=True), nullable=True))
    op.create_index("ix_stages_status_heartbeat", "stages", ["status", "heartbeat_at"])


def downgrade() -> None:
    op.drop_index("ix_stages_status_heartbeat", table_name="stages")
    op.drop_column("stages", "stalled_at")
    op.drop_column("stages", "heartbeat_at")

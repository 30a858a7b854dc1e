"""night clock and cameras: time zone, camera clock, start time, camera model

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-28
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0006"
down_revision: str | None = "0005"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.add_column("nights", sa.Column("time_zone", sa.String(length=64), nullable=True))
    op.add_column(
        "nights",
        sa.Column("camera_clock", sa.String(length=8), server_default="local", nullable=False),
    )
    op.add_column("nights", sa.Column("start_time", sa.DateTime(timezone=True), nullable=True))
    op.add_column("nights", sa.Column("camera_model", sa.String(length=100), nullable=True))


def downgrade() -> None:
    for column in ("camera_model", "start_time", "camera_clock", "time_zone"):
        op.drop_column("nights", column)

"""part checksums: per-part SHA-256 while uploading, a checksum of them per file

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-28
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = "0005"
down_revision: str | None = "0004"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.add_column(
        "input_files",
        sa.Column(
            "part_checksums",
            postgresql.JSONB(astext_type=sa.Text()),
            server_default="{}",
            nullable=False,
        ),
    )
    op.add_column("input_files", sa.Column("checksum", sa.String(length=64), nullable=True))
    op.alter_column("input_files", "sha256", existing_type=sa.String(length=64), nullable=True)


def downgrade() -> None:
    op.execute("UPDATE input_files SET sha256 = repeat('0', 64) WHERE sha256 IS NULL")
    op.alter_column("input_files", "sha256", existing_type=sa.String(length=64), nullable=False)
    op.drop_column("input_files", "checksum")
    op.drop_column("input_files", "part_checksums")

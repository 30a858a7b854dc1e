"""team tokens: several per team, with expiry and revocation (rotation)

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-28
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "team_tokens",
        sa.Column("id", sa.Uuid(), nullable=False),
        sa.Column("team_id", sa.Uuid(), nullable=False),
        sa.Column("token_hash", sa.String(length=64), nullable=False),
        sa.Column("label", sa.String(length=100), nullable=False),
        sa.Column(
            "created_at", sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False
        ),
        sa.Column("expires_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("revoked_at", sa.DateTime(timezone=True), nullable=True),
        sa.ForeignKeyConstraint(
            ["team_id"], ["teams.id"], name=op.f("fk_team_tokens_team_id_teams")
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_team_tokens")),
        sa.UniqueConstraint("token_hash", name=op.f("uq_team_tokens_token_hash")),
    )
    op.create_index(op.f("ix_team_tokens_team_id"), "team_tokens", ["team_id"])
    # Every team keeps the token it has (its first, labelled as such).
    op.execute(
        "INSERT INTO team_tokens (id, team_id, token_hash, label, created_at) "
        "SELECT gen_random_uuid(), id, token_hash, 'initial', created_at FROM teams"
    )
    op.drop_constraint("uq_teams_token_hash", "teams", type_="unique")
    op.drop_column("teams", "token_hash")


def downgrade() -> None:
    op.add_column("teams", sa.Column("token_hash", sa.String(length=64), nullable=True))
    # The newest token still valid (or else a random, unusable one) becomes the team's.
    op.execute(
        "UPDATE teams SET token_hash = coalesce((SELECT t.token_hash FROM team_tokens t "
        "WHERE t.team_id = teams.id AND t.revoked_at IS NULL ORDER BY t.created_at DESC "
        "LIMIT 1), md5(random()::text) || md5(random()::text))"
    )
    op.alter_column("teams", "token_hash", nullable=False)
    op.create_unique_constraint("uq_teams_token_hash", "teams", ["token_hash"])
    op.drop_index(op.f("ix_team_tokens_team_id"), table_name="team_tokens")
    op.drop_table("team_tokens")

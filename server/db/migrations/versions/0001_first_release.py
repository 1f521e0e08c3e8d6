"""The first release's tables: tuning sessions and their feedback events.

Revision 0001 (the first), as `server/db/tables.py` had them when the web app shipped (before any column was
added at start-up).
"""

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "rba_session",
        sa.Column("domain", sa.String(length=64), nullable=False),
        sa.Column("method", sa.String(length=32), nullable=False),
        sa.Column("rep", sa.String(length=32), nullable=False),
        sa.Column("id", sa.String(length=32), nullable=False),
        sa.Column("model_version", sa.String(length=128), nullable=False),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.Column("step", sa.Integer(), nullable=False),
        sa.Column("current_rollout_id", sa.String(length=128), nullable=False),
        sa.Column("agent_state", sa.JSON(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id"),
    )
    op.create_index("ix_rba_session_status", "rba_session", ["status"])
    op.create_table(
        "rba_feedback",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("session_id", sa.String(length=32), nullable=False),
        sa.Column("step", sa.Integer(), nullable=False),
        sa.Column("feedback", sa.JSON(), nullable=False),
        sa.Column("rollout_before", sa.String(length=128), nullable=False),
        sa.Column("rollout_after", sa.String(length=128), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(["session_id"], ["rba_session.id"]),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("session_id", "step", name="uq_feedback_session_step"),
    )
    op.create_index("ix_rba_feedback_session_id", "rba_feedback", ["session_id"])


def downgrade() -> None:
    op.drop_table("rba_feedback")
    op.drop_table("rba_session")

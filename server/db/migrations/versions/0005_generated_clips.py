"""Generation in the app: a session says whether its agent makes new behaviours, and what it made is kept.

Revision 0005 (after 0004): ``rba_session.generate`` (false for every session before) and
``rba_generated_clip``, the params and seed that remake each generated rollout.
"""

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "rba_generated_clip",
        sa.Column("id", sa.String(length=128), nullable=False),
        sa.Column("domain", sa.String(length=64), nullable=False),
        sa.Column("params", sa.JSON(), nullable=False),
        sa.Column("seed", sa.Integer(), nullable=False),
        sa.Column("proxies", sa.JSON(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id"),
    )
    op.add_column("rba_session", sa.Column("generate", sa.Boolean(), server_default=sa.false(), nullable=False))


def downgrade() -> None:
    op.drop_column("rba_session", "generate")
    op.drop_table("rba_generated_clip")

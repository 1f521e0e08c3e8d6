"""A training job names the replica running it and when that replica last said it is alive.

Revision 0004 (after 0003): the columns start-up used to add by hand for API replicas on one database.
"""

import sqlalchemy as sa
from alembic import op

from server.db.migrations import add_missing_columns

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None


def upgrade() -> None:
    add_missing_columns("rba_train_job", sa.Column("owner", sa.String(length=160), nullable=True),
                        sa.Column("heartbeat_at", sa.DateTime(timezone=True), nullable=True))


def downgrade() -> None:
    op.drop_column("rba_train_job", "heartbeat_at")
    op.drop_column("rba_train_job", "owner")

"""A training job says whether it learned from the labels marked on the admin page too.

Revision 0003 (after 0002). No start-up ALTER ever added this column, so jobs tables from 0002 lacked it;
jobs from before it had no page labels to learn from.
"""

import sqlalchemy as sa
from alembic import op

from server.db.migrations import add_missing_columns

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    add_missing_columns("rba_train_job", sa.Column("include_page_labels", sa.Boolean(), nullable=False,
                                                   server_default=sa.false()))


def downgrade() -> None:
    op.drop_column("rba_train_job", "include_page_labels")

"""A training job records each stage's first and latest progress report, so its time left comes from its own rates.

Revision 0007 (after 0006): ``rba_train_job.stages`` (JSON, null for every job before: estimated from typical
durations alone).
"""

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("rba_train_job", sa.Column("stages", sa.JSON(), nullable=True))


def downgrade() -> None:
    op.drop_column("rba_train_job", "stages")

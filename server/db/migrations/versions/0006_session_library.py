"""A session names the serve library its clip ids come from, so a rebuilt library cannot pass for it.

Revision 0006 (after 0005): ``rba_session.library_version``, the serve library's content hash at the session's
start (null for every session before: not checked).
"""

import sqlalchemy as sa
from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("rba_session", sa.Column("library_version", sa.String(length=64), nullable=True))


def downgrade() -> None:
    op.drop_column("rba_session", "library_version")

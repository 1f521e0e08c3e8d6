"""Model versions and the admin's tables; a session records the model set it started on.

Revision 0002 (after 0001): the admin tables as they first shipped (jobs without ``include_page_labels``),
and ``rba_session.model_set``, which start-up used to add by hand; rows from before it ran on the built-in
models.
"""

import sqlalchemy as sa
from alembic import op

from server.db.migrations import add_missing_columns

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def _created_at() -> sa.Column:
    return sa.Column("created_at", sa.DateTime(timezone=True), nullable=False)


def upgrade() -> None:
    op.create_table(
        "rba_active_model",
        sa.Column("domain", sa.String(length=64), nullable=False),
        sa.Column("version", sa.String(length=64), nullable=False),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("domain"),
    )
    op.create_table(
        "rba_attribute",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("domain", sa.String(length=64), nullable=False),
        sa.Column("name", sa.String(length=32), nullable=False),
        sa.Column("description", sa.String(length=300), nullable=False),
        _created_at(),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("domain", "name", name="uq_attribute_domain_name"),
    )
    op.create_index("ix_rba_attribute_domain", "rba_attribute", ["domain"])
    op.create_table(
        "rba_dataset",
        sa.Column("id", sa.String(length=40), nullable=False),
        sa.Column("domain", sa.String(length=64), nullable=False),
        sa.Column("filename", sa.String(length=200), nullable=False),
        sa.Column("trajectories", sa.Integer(), nullable=False),
        sa.Column("labels", sa.Integer(), nullable=False),
        sa.Column("new_attributes", sa.JSON(), nullable=False),
        _created_at(),
        sa.PrimaryKeyConstraint("id"),
    )
    op.create_index("ix_rba_dataset_domain", "rba_dataset", ["domain"])
    op.create_table(
        "rba_label",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("domain", sa.String(length=64), nullable=False),
        sa.Column("kind", sa.String(length=16), nullable=False),
        sa.Column("attribute", sa.String(length=32), nullable=False),
        sa.Column("payload", sa.JSON(), nullable=False),
        _created_at(),
        sa.PrimaryKeyConstraint("id"),
    )
    op.create_index("ix_rba_label_domain", "rba_label", ["domain"])
    op.create_table(
        "rba_model_version",
        sa.Column("version", sa.String(length=64), nullable=False),
        sa.Column("domain", sa.String(length=64), nullable=False),
        sa.Column("method", sa.String(length=32), nullable=False),
        sa.Column("rep", sa.String(length=32), nullable=False),
        sa.Column("job_id", sa.String(length=32), nullable=False),
        sa.Column("attributes", sa.JSON(), nullable=False),
        sa.Column("held_out", sa.JSON(), nullable=False),
        _created_at(),
        sa.PrimaryKeyConstraint("version"),
    )
    op.create_index("ix_rba_model_version_domain", "rba_model_version", ["domain"])
    _train_job()
    add_missing_columns("rba_session", sa.Column("model_set", sa.String(length=64), nullable=False,
                                                 server_default="builtin"))


def _train_job() -> None:
    op.create_table(
        "rba_train_job",
        sa.Column("id", sa.String(length=32), nullable=False),
        sa.Column("domain", sa.String(length=64), nullable=False),
        sa.Column("busy_domain", sa.String(length=64), nullable=True),
        sa.Column("method", sa.String(length=32), nullable=False),
        sa.Column("rep", sa.String(length=32), nullable=False),
        sa.Column("preset", sa.String(length=16), nullable=False),
        sa.Column("datasets", sa.JSON(), nullable=False),
        sa.Column("state", sa.String(length=16), nullable=False),
        sa.Column("stage", sa.String(length=64), nullable=False),
        sa.Column("step", sa.Integer(), nullable=False),
        sa.Column("total", sa.Integer(), nullable=False),
        sa.Column("loss", sa.Float(), nullable=True),
        sa.Column("held_out", sa.JSON(), nullable=True),
        sa.Column("log_tail", sa.Text(), nullable=False),
        sa.Column("error", sa.Text(), nullable=True),
        sa.Column("version", sa.String(length=64), nullable=True),
        _created_at(),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("busy_domain"),
    )
    op.create_index("ix_rba_train_job_domain", "rba_train_job", ["domain"])


def downgrade() -> None:
    op.drop_column("rba_session", "model_set")
    for table in ("rba_train_job", "rba_model_version", "rba_label", "rba_dataset", "rba_attribute",
                  "rba_active_model"):
        op.drop_table(table)

"""Studies with people: a study, its participants (token hashes), their trials, answers and questionnaires.

Revision 0008 (after 0007): five new tables, ``rba_study`` and ``rba_study_{participant,trial,answer,questionnaire}``;
no existing table changes.
"""

import sqlalchemy as sa
from alembic import op

revision = "0008"
down_revision = "0007"
branch_labels = None
depends_on = None


def _study() -> None:
    op.create_table('rba_study',
    sa.Column('id', sa.String(length=32), nullable=False),
    sa.Column('name', sa.String(length=120), nullable=False),
    sa.Column('domain', sa.String(length=64), nullable=False),
    sa.Column('config', sa.JSON(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.PrimaryKeyConstraint('id')
    )


def _study_participant() -> None:
    op.create_table('rba_study_participant',
    sa.Column('id', sa.String(length=32), nullable=False),
    sa.Column('study_id', sa.String(length=32), nullable=False),
    sa.Column('number', sa.Integer(), nullable=False),
    sa.Column('token_hash', sa.String(length=64), nullable=False),
    sa.Column('consented_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('questionnaire_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('withdrawn_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['study_id'], ['rba_study.id'], ),
    sa.PrimaryKeyConstraint('id'),
    sa.UniqueConstraint('study_id', 'number', name='uq_participant_study_number'),
    sa.UniqueConstraint('token_hash')
    )
    with op.batch_alter_table('rba_study_participant', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_rba_study_participant_study_id'), ['study_id'], unique=False)


def _study_questionnaire() -> None:
    op.create_table('rba_study_questionnaire',
    sa.Column('participant_id', sa.String(length=32), nullable=False),
    sa.Column('satisfaction', sa.JSON(), nullable=False),
    sa.Column('usability', sa.JSON(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['participant_id'], ['rba_study_participant.id'], ),
    sa.PrimaryKeyConstraint('participant_id')
    )


def _study_trial() -> None:
    op.create_table('rba_study_trial',
    sa.Column('id', sa.String(length=32), nullable=False),
    sa.Column('participant_id', sa.String(length=32), nullable=False),
    sa.Column('position', sa.Integer(), nullable=False),
    sa.Column('condition', sa.Integer(), nullable=False),
    sa.Column('target_rollout_id', sa.String(length=128), nullable=True),
    sa.Column('session_id', sa.String(length=32), nullable=True),
    sa.Column('answers', sa.Integer(), nullable=False),
    sa.Column('feedbacks', sa.Integer(), nullable=False),
    sa.Column('ended', sa.String(length=16), nullable=True),
    sa.Column('final_rollout_id', sa.String(length=128), nullable=True),
    sa.Column('distance', sa.Float(), nullable=True),
    sa.Column('success', sa.Boolean(), nullable=True),
    sa.Column('started_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('ended_at', sa.DateTime(timezone=True), nullable=True),
    sa.ForeignKeyConstraint(['participant_id'], ['rba_study_participant.id'], ),
    sa.ForeignKeyConstraint(['session_id'], ['rba_session.id'], ),
    sa.PrimaryKeyConstraint('id'),
    sa.UniqueConstraint('participant_id', 'position', name='uq_trial_participant_position')
    )
    with op.batch_alter_table('rba_study_trial', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_rba_study_trial_participant_id'), ['participant_id'], unique=False)


def _study_answer() -> None:
    op.create_table('rba_study_answer',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('trial_id', sa.String(length=32), nullable=False),
    sa.Column('step', sa.Integer(), nullable=False),
    sa.Column('rollout_id', sa.String(length=128), nullable=False),
    sa.Column('feedback', sa.JSON(), nullable=False),
    sa.Column('ms', sa.Integer(), nullable=False),
    sa.Column('replays', sa.Integer(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['trial_id'], ['rba_study_trial.id'], ),
    sa.PrimaryKeyConstraint('id'),
    sa.UniqueConstraint('trial_id', 'step', name='uq_answer_trial_step')
    )
    with op.batch_alter_table('rba_study_answer', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_rba_study_answer_trial_id'), ['trial_id'], unique=False)


def upgrade() -> None:
    _study()
    _study_participant()
    _study_questionnaire()
    _study_trial()
    _study_answer()


def downgrade() -> None:
    with op.batch_alter_table('rba_study_answer', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_rba_study_answer_trial_id'))

    op.drop_table('rba_study_answer')
    with op.batch_alter_table('rba_study_trial', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_rba_study_trial_participant_id'))

    op.drop_table('rba_study_trial')
    op.drop_table('rba_study_questionnaire')
    with op.batch_alter_table('rba_study_participant', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_rba_study_participant_study_id'))

    op.drop_table('rba_study_participant')
    op.drop_table('rba_study')

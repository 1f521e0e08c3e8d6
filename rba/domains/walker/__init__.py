"""The walker domain: dm_control's planar ``walker`` taking three scripted steps.

One module a part, in the style of dm_control's suite:

* ``physics``: the model's dimensions (:class:`WalkerGeometry`) and :class:`WalkerPhysics`, MuJoCo's model and
  data with named getters (``torso_height()``, ``hip_position()``, ``foot_positions()``...);
* ``gait``: the skill: what the parameters command (:class:`GaitPlan`) and the :class:`GaitController` that
  turns the getters into each physics step's motor commands and torso assist;
* ``measure``: what a rollout records (its states, replay frames, falls) and the attributes' proxies from it;
* ``sim``: the walker stepped one physics step at a time (``rba.gym``) and the gait as a policy: on the sim's
  own physics it is the rollout's skill; reading observations alone (an ``ObservedWalker``, the same getters
  filled from an observation) it is ``rba.gym``'s;
* ``domain``: :class:`Walker` and its raw view :class:`WalkerRaw`, which ``rba.domains`` registers.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported: off-screen rendering by default

from rba.domains.walker.domain import Walker, WalkerRaw
from rba.domains.walker.gait import GaitController, GaitPlan
from rba.domains.walker.measure import FRAME_RATE, STATE_EVERY
from rba.domains.walker.physics import WalkerGeometry, WalkerPhysics

__all__ = ["FRAME_RATE", "STATE_EVERY", "GaitController", "GaitPlan", "Walker", "WalkerGeometry", "WalkerPhysics",
           "WalkerRaw"]

"""Lane change seen as images (the paper's setting): states are VAE latents of rendered frames.

The scene, the skill, the attributes and the clips are ``lane_change``'s. Only the states
differ: at each 5 Hz state time the scene is rendered as a 64x64 grayscale frame (60 m of road
across, the ego car 70 % of the way across so that a follower up to 35 m behind is in view when
the change starts); that frame and the two from the previous state times, stacked as channels,
go through a small convolutional VAE (``rba.learn.vae``) and the latent mean is the state.
The domain only loads that VAE (``models/lane_change_image/vae-frames.pt`` and its card);
``rba.learn.training.train_frame_vae`` makes it, which ``rba build lane_change --states image`` does
when it is missing. No ``rba.gym`` env: a policy cannot steer from latents (``rba.domains.lane_change``).
"""

from __future__ import annotations

import threading

import numpy as np

from rba.domains.base import Domain, Rollout
from rba.domains.lane_change import DECIDE_EVERY, LaneChange
from rba.learn.vae import SIZE, STACK

IMAGE_VIEW = 60.0  # m of road across a 64-pixel frame (≈ 1 px/m; a lane is 4 px)
EGO_AT = 0.7  # ego 42 m from the left edge: the follower (≤ 35 m behind, centre to centre) stays in view
VIEW = {"view_m": IMAGE_VIEW, "ego_at": EGO_AT}  # what the VAE's card records of the frames it was trained on
LATENT = 16
MAKE_VAE = "`rba build lane_change --states image` (it trains the VAE when missing)"


class LaneChangeImage(LaneChange):
    name = "lane_change_image"
    state_dim = LATENT
    ranker_steps = 3200  # gap from latents underfits: held-out 0.927 at 800 steps, 0.945 at 1,600, 0.956 at 3,200
    state_encoder = ("vae", "frames")
    frame_view = VIEW
    serve_size = 2400  # an image rollout costs ~6x a kinematic one (79 vs 14 ms, `rba build`); 2,400 reach 97.5 %
    # no env: see the module docstring
    simulator, skill_policy, observed_proxies = Domain.simulator, Domain.skill_policy, Domain.observed_proxies

    def __init__(self) -> None:
        super().__init__()
        self._vae_model = None
        self._vae_lock = threading.Lock()

    def frames(self, rollout: Rollout) -> np.ndarray:
        """uint8 [T, 3, 64, 64]: at each state time, the frames of this and the two previous state times."""
        n = len(rollout.states)
        rows = np.arange(n) * DECIDE_EVERY + DECIDE_EVERY - 1  # replay row of each state
        rgb = self.render(rollout, SIZE, SIZE, rows, view=IMAGE_VIEW, ego_at=EGO_AT)
        gray = np.stack([f.mean(2) for f in rgb]).astype(np.uint8)
        idx = np.clip(np.arange(n)[:, None] - np.arange(STACK - 1, -1, -1)[None, :], 0, n - 1)
        return gray[idx]

    def _vae(self):
        with self._vae_lock:
            if self._vae_model is None:
                from rba.core.artifacts import ModelNotFoundError, load_model
                from rba.core.store import model_files

                try:
                    vae = load_model(self.name, *self.state_encoder)
                except ModelNotFoundError as e:
                    path = model_files().weights(self.name, *self.state_encoder)
                    raise ModelNotFoundError(f"no frame VAE for {self.name} at {path} (and its .json card): "
                                             f"make it with {MAKE_VAE}") from e
                seen = {k: vae.card["architecture"].get(k) for k in VIEW}
                if seen != VIEW:
                    raise ValueError(f"the frame VAE was trained on another view ({seen}; this code renders {VIEW}): "
                                     f"delete models/{self.name}/vae-frames.* and run {MAKE_VAE}")
                self._vae_model = vae.model
            return self._vae_model

    def kinematic_rollout(self, params: dict[str, float], seed: int) -> Rollout:
        """The rollout with ``lane_change``'s kinematic states (what the frames are rendered from)."""
        return super().rollout(params, seed)

    def rollout(self, params: dict[str, float], seed: int) -> Rollout:
        r = self.kinematic_rollout(params, seed)
        r.domain = self.name
        r.states = self._vae().embed(self.frames(r)).astype(np.float32)
        return r

"""A small convolutional VAE: 64x64 grayscale frames, 3 stacked as channels -> a latent state.

The paper's lane-change states were images encoded this way; ``rba.domains.lane_change_image``
uses the latent mean as the state the RBA models see (``rba.learn.training.train_frame_vae`` makes it).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from rba.core.settings import LibrarySettings
from rba.learn.common import Progress, StepLoop, check_shape, seed_everything

SIZE = 64  # frame side, pixels
STACK = 3  # frames per input


@dataclass
class VAEConfig:
    latent: int = 16
    epochs: int = 6
    batch: int = 128
    lr: float = 1e-3
    beta: float = 0.5  # weight of the KL term
    seed: int = 0


class FrameVAE(nn.Module):
    """Encoder 64 -> 32 -> 16 -> 8 (stride-2 convs), latent ``latent``; decoder mirrored."""

    def __init__(self, latent: int = 16) -> None:
        super().__init__()
        self.latent = latent
        self.enc = nn.Sequential(
            nn.Conv2d(STACK, 16, 4, 2, 1), nn.ReLU(), nn.Conv2d(16, 32, 4, 2, 1), nn.ReLU(),
            nn.Conv2d(32, 64, 4, 2, 1), nn.ReLU(), nn.Flatten())
        self.mu = nn.Linear(64 * 8 * 8, latent)
        self.logvar = nn.Linear(64 * 8 * 8, latent)
        self.dec_in = nn.Linear(latent, 64 * 8 * 8)
        self.dec = nn.Sequential(
            nn.ConvTranspose2d(64, 32, 4, 2, 1), nn.ReLU(), nn.ConvTranspose2d(32, 16, 4, 2, 1), nn.ReLU(),
            nn.ConvTranspose2d(16, STACK, 4, 2, 1))

    def encode(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(μ, log σ²) float32[N, latent] for frames float32[N, 3, 64, 64] in [0, 1]."""
        check_shape(x, None, STACK, SIZE, SIZE, name="frames")
        h = self.enc(x)
        return self.mu(h), self.logvar(h)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """Logits float32[N, 3, 64, 64]."""
        return self.dec(self.dec_in(z).view(-1, 64, 8, 8))

    @torch.no_grad()
    def embed(self, frames: np.ndarray, batch: int = 512) -> np.ndarray:
        """The latent mean float32[N, latent] of uint8 frames [N, 3, 64, 64]."""
        self.eval()
        out = [self.encode(torch.as_tensor(frames[i:i + batch], dtype=torch.float32) / 255.0)[0]
               for i in range(0, len(frames), batch)]
        return torch.cat(out).numpy() if out else np.zeros((0, self.latent), np.float32)


def train_vae(frames: np.ndarray, cfg: VAEConfig, progress: Progress | None = None) -> tuple[FrameVAE, dict]:
    """Fit the VAE on uint8 frames [N, 3, 64, 64]; returns the model and its final losses."""
    gen = seed_everything(cfg.seed)
    torch.set_num_threads(LibrarySettings().train_threads)
    model = FrameVAE(cfg.latent)
    data = torch.as_tensor(frames)
    n = len(data)
    steps = max(cfg.epochs * n // cfg.batch, 1)
    loop = StepLoop(torch.optim.Adam(model.parameters(), lr=cfg.lr), steps, progress, report_every=100)
    for step in range(steps):
        x = data[torch.randint(n, (cfg.batch,), generator=gen)].float() / 255.0
        mu, logvar = model.encode(x)
        z = mu + torch.randn(mu.shape, generator=gen) * (0.5 * logvar).exp()
        recon = F.binary_cross_entropy_with_logits(model.decode(z), x, reduction="sum") / len(x)
        kl = -0.5 * torch.sum(1 + logvar - mu.pow(2) - logvar.exp()) / len(x)
        loop.step(step, recon + cfg.beta * kl)
    model.eval()
    return model, {"frames": n, "steps": steps, "reconstruction": round(recon.item(), 2), "kl": round(kl.item(), 2),
                   "config": asdict(cfg)}

"""ζσ as a smooth function of the skill's parameters: a local linear fit over the serve library.

ζσ scores a clip's states. Two clips of nearly the same parameters (other seeds) differ in ζσ by more than
their proxies do, so near a high-precision target ζσ orders clips only by chance
(decision 0008). Where the proxies move smoothly with the parameters, a fit of
ζσ over the parameters averages that noise away: LOESS, a weighted least-squares plane through the
``neighbours`` serve clips nearest in the unit parameter box (tricube weights), read at its centre.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from rba.data.library import SkillLibrary
    from rba.domains.base import ParamSpace

CHUNK = 256  # points fitted at once: a CHUNK × N distance matrix
RIDGE = 1e-9  # keeps a plane through clips on a line solvable


@dataclass(frozen=True)
class ZetaSurface:
    """ζ̃(p): the local linear fit of the library's ζσ at unit parameters p (module docstring)."""

    units: np.ndarray  # float64[N, d]: the library clips' free parameters in [0, 1]
    zeta: np.ndarray  # float64[N, k]: their ζσ
    neighbours: int

    def __post_init__(self) -> None:
        if self.units.ndim != 2 or self.zeta.ndim != 2 or len(self.units) != len(self.zeta):
            raise ValueError(f"units [N, d] and zeta [N, k] of one library, got {self.units.shape} and "
                             f"{self.zeta.shape}")
        if self.neighbours < 2:
            raise ValueError(f"a local plane needs at least 2 neighbours, got {self.neighbours}")

    @classmethod
    def of_library(cls, library: SkillLibrary, zeta: np.ndarray, space: ParamSpace, neighbours: int) -> ZetaSurface:
        """The surface through ``library``'s clips (their ζσ ``zeta``, float[N, k]) in ``space``'s unit box."""
        units = np.array([space.to_unit(dict(zip(library.param_names, map(float, p), strict=True)))
                          for p in library.params])
        return cls(units, np.asarray(zeta, np.float64), neighbours)

    def at(self, space: ParamSpace, params: dict[str, float]) -> np.ndarray:
        """ζ̃ of one clip's parameters: float64[k]."""
        return self(space.to_unit(params))[0]

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """ζ̃ at each of ``points`` (float[M, d] or [d]): float64[M, k]."""
        points = np.atleast_2d(np.asarray(points, np.float64))
        if points.shape[1] != self.units.shape[1]:
            raise ValueError(f"points have {points.shape[1]} parameters; the surface has {self.units.shape[1]}")
        return np.concatenate([self._fit(points[i:i + CHUNK]) for i in range(0, len(points), CHUNK)])

    def _fit(self, points: np.ndarray) -> np.ndarray:
        k = min(self.neighbours, len(self.units))
        dist = np.linalg.norm(points[:, None, :] - self.units[None], axis=2)  # [M, N]
        idx = np.argpartition(dist, k - 1, axis=1)[:, :k]  # [M, k]
        near = np.take_along_axis(dist, idx, axis=1)
        w = (1 - (near / (near.max(axis=1, keepdims=True) + 1e-12)) ** 3) ** 3 + 1e-3  # tricube, none zero
        x = np.concatenate([np.ones((*idx.shape, 1)), self.units[idx] - points[:, None, :]], axis=2)  # [M, k, d+1]
        xw = x * w[..., None]
        a = np.einsum("mki,mkj->mij", xw, x) + RIDGE * np.eye(x.shape[2])
        b = np.einsum("mki,mkz->miz", xw, self.zeta[idx])
        return np.linalg.solve(a, b)[:, 0, :]  # the plane's value at the point itself


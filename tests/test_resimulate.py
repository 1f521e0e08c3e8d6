"""The shipped libraries re-simulate bit-identically: a refactor of a domain must not change a single bit.

For every registered domain with libraries under ``data/``, a deterministic sample of stored rollouts
of each split is simulated again from its parameters and seed; states, replay and success must equal the
stored ones exactly (replay is stored as float32, so it is compared at float32), proxies within ``PROXY_RTOL``:
they are float64 all the way, and float64 reductions (numpy's SIMD paths, libm) round differently across
CPUs and builds in the last bit (the manipulator's instability and lane_change's sharpness differ by
≈ 1e-15 relative on another machine than the one that built the libraries, the float32 states not at all).

One exception: lane_change_image's states are VAE latents, and the shipped library's latents were computed
by a torch build/CPU whose float32 convolutions round differently from this machine's (≈ 5e-7 apart,
whatever the thread count or batch); its simulation (replay, proxies, success) is still compared exactly.
"""

from __future__ import annotations

import numpy as np
import pytest

from rba.core.store import Store
from rba.data.library import SPLITS, SkillLibrary
from rba.domains import domain_names, get_domain

PER_SPLIT = 4  # rollouts re-simulated per split: first, last and two in between (~2 s per domain)
PROXY_RTOL = 1e-9  # proxies: float64, equal but for the last bits across machines (the module docstring)
ENCODED_ATOL = 1e-5  # states a learned encoder makes (float32 network outputs): not bitwise across torch builds


def _sample(n: int) -> list[int]:
    """Deterministic, spread-out rollout indices of a library of ``n``."""
    return sorted({int(i) for i in np.linspace(0, n - 1, PER_SPLIT).round()})


def _cases() -> list[tuple[str, str]]:
    return [(d, s) for d in domain_names() if d != "toy" for s in SPLITS]


@pytest.mark.parametrize(("domain_name", "split"), _cases())
def test_stored_rollouts_resimulate_exactly(domain_name: str, split: str) -> None:
    store = Store.from_settings()
    if not store.libraries.complete(domain_name, split):
        pytest.skip(f"no shipped {domain_name}/{split} library")
    lib = SkillLibrary.load(domain_name, split)
    domain = get_domain(domain_name)  # a shipped library's state encoder is shipped too: a missing one fails
    for i in _sample(len(lib)):
        stored = lib.rollout(i)
        again = domain.rollout(stored.params, stored.seed)
        if domain.state_encoder is not None:
            np.testing.assert_allclose(again.states, stored.states, rtol=0, atol=ENCODED_ATOL,
                                       err_msg=f"{stored.id} states")
        else:
            np.testing.assert_array_equal(again.states, stored.states, err_msg=f"{stored.id} states")
        np.testing.assert_array_equal(np.asarray(again.replay, dtype=np.float32), stored.replay,
                                      err_msg=f"{stored.id} replay")
        assert again.proxies == pytest.approx(stored.proxies, rel=PROXY_RTOL, abs=0.0), stored.id
        assert again.success == stored.success, stored.id

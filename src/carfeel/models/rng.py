"""A tiny pure random number generator (SplitMix64) whose whole state is one int.

Models keep the int in their state, so a step stays a pure function and one seed gives one result,
in the offline simulator and in the real-time loop alike. Not for cryptography.
"""

from __future__ import annotations

_MASK64 = (1 << 64) - 1

MAX_SEED = _MASK64
"""Seeds are the 64-bit state of SplitMix64: a larger one would alias a smaller one."""


def seed_state(seed: int) -> int:
    """The generator state for a seed (any int)."""
    return seed & _MASK64


def next_uniform(rng_state: int) -> tuple[int, float]:
    """Return (new_state, u) with u uniform in [0, 1)."""
    rng_state = (rng_state + 0x9E3779B97F4A7C15) & _MASK64
    z = rng_state
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK64
    z ^= z >> 31
    return rng_state, (z >> 11) * (1.0 / (1 << 53))

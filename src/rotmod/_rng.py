"""A small counter-free random number generator usable inside numba kernels.

``xoshiro256+`` (Blackman & Vigna 2018): 256 bits of state, period 2^256 - 1, and the top
53 bits of each output make a uniform double in [0, 1).  Each parallel chunk of the Monte
Carlo owns one state, seeded from :class:`numpy.random.SeedSequence` children
(:func:`chunk_states`), so results depend on the seed and the chunking but not on the number
of threads or their scheduling.  The detectors' energy-response Monte Carlo
(:mod:`rotmod.spectral.detector`) draws from the same generator, which is why it lives with
the rules rather than inside :mod:`rotmod.montecarlo`.

The Poisson sampler is numpy's: multiplication (inversion) for ``lam < 10`` and Hörmann's
PTRS transformed rejection for ``lam >= 10`` (W. Hörmann, Insurance: Mathematics and
Economics 12, 39 (1993)).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from rotmod.errors import ParameterError

__all__ = ["chunk_states", "next_double", "poisson", "seed_sequence"]

_U11 = np.uint64(11)
_U17 = np.uint64(17)
_U45 = np.uint64(45)
_U19 = np.uint64(19)
_TWO_M53 = 1.0 / 9007199254740992.0


@njit(cache=True, inline="always")
def next_double(s: np.ndarray) -> float:
    """Next uniform double in [0, 1) from the xoshiro256+ state ``s`` (uint64[4], updated)."""
    s0 = s[0]
    s1 = s[1]
    s2 = s[2] ^ s0
    s3 = s[3] ^ s1
    result = s0 + s[3]
    t = s1 << _U17
    s1 = s1 ^ s2
    s0 = s0 ^ s3
    s2 = s2 ^ t
    s3 = (s3 << _U45) | (s3 >> _U19)
    s[0] = s0
    s[1] = s1
    s[2] = s2
    s[3] = s3
    return (result >> _U11) * _TWO_M53


@njit(cache=True)
def poisson(s: np.ndarray, lam: float) -> int:
    """One Poisson variate of mean ``lam`` (>= 0) drawn with the state ``s``."""
    if lam <= 0.0:
        return 0
    if lam < 10.0:
        enlam = math.exp(-lam)
        k = 0
        prod = 1.0
        while True:
            prod *= next_double(s)
            if prod > enlam:
                k += 1
            else:
                return k
    slam = math.sqrt(lam)
    loglam = math.log(lam)
    b = 0.931 + 2.53 * slam
    a = -0.059 + 0.02483 * b
    invalpha = 1.1239 + 1.1328 / (b - 3.4)
    vr = 0.9277 - 3.6224 / (b - 2.0)
    while True:
        uu = next_double(s) - 0.5
        v = next_double(s)
        us = 0.5 - abs(uu)
        k = math.floor((2.0 * a / us + b) * uu + lam + 0.43)
        if us >= 0.07 and v <= vr:
            return int(k)
        if k < 0 or (us < 0.013 and v > us):
            continue
        if v <= 0.0:
            continue
        if (math.log(v) + math.log(invalpha) - math.log(a / (us * us) + b)) <= (
            -lam + k * loglam - math.lgamma(k + 1.0)
        ):
            return int(k)


def seed_sequence(seed: Any) -> np.random.SeedSequence:
    """Turn ``seed`` (None, int, SeedSequence or numpy Generator) into a SeedSequence.

    A :class:`numpy.random.Generator` is advanced by one draw of four 63-bit integers, so a
    seeded Generator gives reproducible results.  The legacy ``RandomState`` is refused.
    """
    if isinstance(seed, np.random.SeedSequence):
        return seed
    if isinstance(seed, np.random.Generator):
        return np.random.SeedSequence(seed.integers(0, 2**63, size=4).tolist())
    if seed is None:
        return np.random.SeedSequence()
    if isinstance(seed, np.random.RandomState):
        raise ParameterError(
            "seed must be None, an int, a SeedSequence or a numpy Generator; the legacy "
            "RandomState is not supported"
        )
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ParameterError(
            f"seed must be None, an int >= 0, a SeedSequence or a numpy Generator, got {seed!r}"
        )
    return np.random.SeedSequence(int(seed))


def chunk_states(root: np.random.SeedSequence, n: int) -> np.ndarray:
    """xoshiro256+ states (uint64[n, 4]) of the next ``n`` children spawned from ``root``."""
    out = np.empty((n, 4), dtype=np.uint64)
    for i, child in enumerate(root.spawn(n)):
        st = child.generate_state(4, np.uint64)
        if not st.any():  # the all-zero state is the one forbidden state
            st[0] = np.uint64(0x9E3779B97F4A7C15)
        out[i] = st
    return out

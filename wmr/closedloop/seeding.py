"""A run's two generators, made the way numpy makes them, without numpy's Python-level cost.

``prepare`` (``wmr.closedloop.runsetup``) gives a run two PCG64 streams, the children
``SeedSequence(seed).spawn(2)`` would give: ``SeedSequence(seed, spawn_key=(i,))``, ``i = 0`` for
the measurement noise and ``i = 1`` for the controller's initialisation
(``runsetup.seed_sequences``).  numpy builds each SeedSequence and draws its state in Python-level
code, ~8 us a stream: a fifth of a short run's set-up.  For a seed that is an integer in
``[0, 2**64)`` :func:`generators` computes the two PCG64 seeds with numpy's SeedSequence
algorithm compiled -- the entropy (the seed's 32-bit words, padded to the pool size because a spawn
key follows, then the key) hashed into a pool of four words (``hashmix`` / ``mix``), then
``generate_state(4, uint64)`` -- and hands them to ``PCG64`` through a minimal ``ISeedSequence``
(:class:`_Words`).  Any other seed (a SeedSequence, a list, a larger integer) goes through numpy.
Same states, same draws (``tests/test_runsetup.py`` checks the states against numpy's over
seeds of one and two words and both keys).
"""

from __future__ import annotations

import numpy as np

from wmr._jit import njit

__all__ = ["generators", "seed_sequences", "spawned_states"]

_M = 0xFFFFFFFF
_INIT_A, _MULT_A = 0x43B0D7E5, 0x931E8875
_INIT_B, _MULT_B = 0x8B51F9DD, 0x58F38DED
_MIX_L, _MIX_R = 0xCA01F9DD, 0x4973F715
_POOL = 4


@njit(inline="always")
def _mul32(a, b):
    """``a b mod 2**32`` for ``a, b < 2**32`` in int64 without overflow (16-bit halves of ``a``)."""
    return (((((a >> 16) * b) & 0xFFFF) << 16) + (a & 0xFFFF) * b) & _M


@njit(inline="always")
def _hashmix(v, h):
    """numpy's ``hashmix``: the mixed value and the next hash constant."""
    v = (v ^ h) & _M
    h = _mul32(h, _MULT_A)
    v = _mul32(v, h)
    return v ^ (v >> 16), h


@njit(inline="always")
def _mix(x, y):
    r = (_mul32(_MIX_L, x) - _mul32(_MIX_R, y)) & _M
    return r ^ (r >> 16)


@njit
def spawned_states(lo, hi, out):
    """The PCG64 seeds of ``SeedSequence(seed, spawn_key=(i,))``, ``i = 0, 1``, as 32-bit words:
    ``out`` (2, 8) int64, row ``i`` the 8 words of ``generate_state(4, uint64)`` (little-endian
    pairs).  ``seed = lo + 2**32 hi``: its one or two words, padded with zeros to the pool size
    (so a one-word seed is ``hi = 0``)."""
    ent = np.zeros(_POOL + 1, dtype=np.int64)
    pool = np.zeros(_POOL, dtype=np.int64)
    for key in range(2):
        ent[0] = lo
        ent[1] = hi
        ent[2] = 0
        ent[3] = 0
        ent[_POOL] = key  # the run entropy is padded to the pool size before a spawn key
        h = _INIT_A
        for i in range(_POOL):
            pool[i], h = _hashmix(ent[i], h)
        for s in range(_POOL):
            for d in range(_POOL):
                if s != d:
                    v, h = _hashmix(pool[s], h)
                    pool[d] = _mix(pool[d], v)
        for s in range(_POOL, _POOL + 1):
            for d in range(_POOL):
                v, h = _hashmix(ent[s], h)
                pool[d] = _mix(pool[d], v)
        hb = _INIT_B
        for i in range(8):
            v = (pool[i % _POOL] ^ hb) & _M
            hb = _mul32(hb, _MULT_B)
            v = _mul32(v, hb)
            out[key, i] = v ^ (v >> 16)


class _Words(np.random.bit_generator.ISeedSequence):
    """An ``ISeedSequence`` that gives ``PCG64`` a precomputed ``generate_state(4, uint64)``."""

    __slots__ = ("_state",)

    def __init__(self, state: np.ndarray):
        self._state = state

    def generate_state(self, n_words, dtype=np.uint32):
        if n_words != 4 or np.dtype(dtype) != np.uint64:  # PCG64 asks for exactly this
            raise ValueError("_Words holds the 4 uint64 words of a PCG64 seed only")
        return self._state


def _fast(seed) -> bool:
    return (isinstance(seed, (int, np.integer)) and not isinstance(seed, bool)
            and 0 <= int(seed) < 2**64)  # fmt: skip


def seed_sequences(seed: int | np.random.SeedSequence):
    """The run's two independent streams: measurement noise and controller initialisation.

    The noise stream depends on the seed only, so every controller of a comparison sees the same
    noise draws (common random numbers).  For a seed given as a number these are the children
    ``SeedSequence(seed).spawn(2)`` would give, made directly (the parent is not needed).
    """
    if isinstance(seed, np.random.SeedSequence):
        return seed.spawn(2)
    return [np.random.SeedSequence(seed, spawn_key=(i,)) for i in range(2)]


def generators(seed, draws: bool = True):
    """``(noise, init)``: ``default_rng`` of the two children of ``seed``
    (:func:`seed_sequences`); ``init`` is None when not ``draws`` (a controller that draws
    nothing: its stream is not made)."""
    if not _fast(seed):
        if draws or isinstance(seed, np.random.SeedSequence):
            noise_ss, init_ss = seed_sequences(seed)
        else:
            noise_ss, init_ss = np.random.SeedSequence(seed, spawn_key=(0,)), None
        return _generator(noise_ss), (_generator(init_ss) if draws else None)
    seed = int(seed)
    words = np.empty((2, 8), dtype=np.int64)
    spawned_states(seed & _M, seed >> 32, words)
    state = words.astype("<u4").view("<u8").astype(np.uint64)  # numpy's little-endian view
    noise = _generator(_Words(state[0]))
    return noise, (_generator(_Words(state[1])) if draws else None)


def _generator(ss) -> np.random.Generator:
    """``np.random.default_rng(ss)``, which is this (a PCG64 generator), without its checks."""
    return np.random.Generator(np.random.PCG64(ss))

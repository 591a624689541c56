"""Random numbers of the tracer (``docs/kernel.md``, random numbers).

Every path owns its numbers, keyed by ``(seed, incident index, chunk index, path index)``,
which is what makes a simulation bit-identical whatever the number of threads and whichever
lane of the kernel traces the path:

* counter-based draws, ``draw(key, n)``: the SplitMix64 finaliser of ``key + n * golden``, the
  ``n``-th 64-bit number of the path whose key is ``key`` (:func:`path_key`); the kernel's
  vectorised event takes two to four per event (:func:`uniform_pair`: two 32-bit uniforms each;
  ``docs/kernel.md``, random numbers);
* a xoshiro256** stream (state ``uint64[4]``) seeded from the path key by :func:`seed_state`:
  for the continuation of a microsurface walk in the lane kernel (variable length) and for whole
  paths in the per-path drivers (:func:`path_state`: the per-path kernel, the CUDA kernel); a
  stream keyed by (seed, incident index, chunk index) for code outside the kernels
  (:func:`stream_state`).
"""

from __future__ import annotations

import numba
import numpy as np

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_U30 = np.uint64(30)
_U27 = np.uint64(27)
_U31 = np.uint64(31)
_U17 = np.uint64(17)
_U45 = np.uint64(45)
_U19 = np.uint64(19)
_U7 = np.uint64(7)
_U57 = np.uint64(57)
_U5 = np.uint64(5)
_U9 = np.uint64(9)
_U11 = np.uint64(11)
_INV_2_53 = 1.0 / 9007199254740992.0
_U32 = np.uint64(32)
_LOW32 = np.uint64(0xFFFFFFFF)
_INV_2_31 = 1.0 / 2147483648.0
_INV_2_32 = 1.0 / 4294967296.0
#: constants that set the per-path keys apart from the per-chunk streams of :func:`stream_state`
_CHUNK_SALT = np.uint64(0x5EED)
_STREAM_SALT = np.uint64(0x243F6A8885A308D3)


@numba.njit(cache=True, error_model='numpy')
def splitmix64(x: np.uint64) -> np.uint64:
    """One SplitMix64 step as a pure function: the mixed value of ``x + golden``."""
    z = x + _GOLDEN
    z = (z ^ (z >> _U30)) * _M1
    z = (z ^ (z >> _U27)) * _M2
    return z ^ (z >> _U31)


@numba.njit(cache=True, error_model='numpy')
def stream_state(seed: np.uint64, incident: np.uint64, chunk: np.uint64) -> np.ndarray:
    """The xoshiro256** state of the stream keyed by (seed, incident index, chunk index)."""
    k = splitmix64(splitmix64(splitmix64(seed) ^ incident) ^ (chunk * _GOLDEN + _U5))
    s = np.empty(4, dtype=np.uint64)
    for i in range(4):
        k = splitmix64(k)
        s[i] = k
    return s


@numba.njit(cache=True, error_model='numpy')
def seed_state(s: np.ndarray, key: np.uint64) -> None:
    """Fill the xoshiro256** state ``s`` (``uint64[4]``) from a path key (SplitMix64 steps)."""
    k = key ^ _STREAM_SALT
    for i in range(4):
        k = splitmix64(k)
        s[i] = k


@numba.njit(cache=True, error_model='numpy', inline='always')
def draw(key: np.uint64, n: np.uint64) -> np.uint64:
    """The ``n``-th 64-bit number of the path keyed ``key``: SplitMix64's finaliser of
    ``key + n * golden`` (no state; vectorisable)."""
    z = key + n * _GOLDEN
    z = (z ^ (z >> _U30)) * _M1
    z = (z ^ (z >> _U27)) * _M2
    return z ^ (z >> _U31)


@numba.njit(cache=True, error_model='numpy', inline='always')
def uniform_pair(h: np.uint64):
    """Two uniforms in [0, 1) on the grid 2^-32 from the two 32-bit halves of ``h``."""
    a = np.int64(h >> _U32)
    b = np.int64(h & _LOW32)
    return float(a) * _INV_2_32, float(b) * _INV_2_32


@numba.njit(cache=True, error_model='numpy', inline='always')
def path_key(chunk: np.uint64, path: np.uint64) -> np.uint64:
    """The key of path ``path`` (index within its chunk) of the chunk keyed ``chunk``."""
    z = chunk ^ (path * _M2)
    z = (z ^ (z >> _U30)) * _M1
    z = (z ^ (z >> _U27)) * _M2
    return z ^ (z >> _U31)


@numba.njit(cache=True, error_model='numpy')
def chunk_key(seed: np.uint64, incident: np.uint64, chunk: np.uint64) -> np.uint64:
    """The key of chunk ``chunk`` of incident direction ``incident`` of a run seeded ``seed``."""
    return path_key(path_key(path_key(_CHUNK_SALT, seed), incident), chunk)


@numba.njit(cache=True, error_model='numpy')
def path_state(s: np.ndarray, seed, stream, chunk, path) -> None:
    """Seed ``s`` (``uint64[4]``) from the key of path ``path`` of chunk ``chunk`` of incident
    ``stream`` of a run seeded ``seed`` (:func:`seed_state` of :func:`path_key` of
    :func:`chunk_key`): the stream a per-path driver traces the path with (the CUDA kernel, the
    per-path kernel)."""
    seed_state(s, path_key(chunk_key(np.uint64(seed), np.uint64(stream), np.uint64(chunk)), np.uint64(path)))


@numba.njit(cache=True, error_model='numpy')
def next_float(s: np.ndarray) -> float:
    """Next uniform double in [0, 1) with 53 random bits; advances the state ``s`` in place."""
    return float(next_u64(s) >> _U11) * _INV_2_53


@numba.njit(cache=True, error_model='numpy')
def next_disk(s: np.ndarray):
    """A point ``(x, y)`` uniform in the unit disk (``x^2 + y^2 < 1``) by rejection from the
    square: each trial takes one 64-bit output, its two 32-bit halves giving ``x`` and ``y`` on a
    grid of step 2^-31 in [-1, 1) (exact in double precision). 4 / pi trials on average; no
    trigonometry."""
    while True:
        r = next_u64(s)
        x = float(r >> _U32) * _INV_2_31 - 1.0
        y = float(r & _LOW32) * _INV_2_31 - 1.0
        if x * x + y * y < 1.0:
            return x, y


@numba.njit(cache=True, error_model='numpy')
def next_u64(s: np.ndarray) -> np.uint64:
    """Next 64-bit output of xoshiro256**; advances the state ``s`` in place."""
    s1 = s[1]
    r = s1 * _U5
    r = ((r << _U7) | (r >> _U57)) * _U9
    t = s1 << _U17
    s[2] ^= s[0]
    s[3] ^= s[1]
    s[1] ^= s[2]
    s[0] ^= s[3]
    s[2] ^= t
    s3 = s[3]
    s[3] = (s3 << _U45) | (s3 >> _U19)
    return r

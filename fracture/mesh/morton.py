"""Morton (Z-order) codes: the integer coordinates of a cell interleaved bit by bit, so that cells near
each other in space get codes near each other (the vertex order of :func:`~fracture.refine.order.spatial_order`
and the bucket order of :mod:`~fracture.mesh.hashgrid`)."""

from __future__ import annotations

import numba
import numpy as np

BITS = 21  # bits per coordinate: three of them fill 63 bits of an int64


@numba.njit(cache=True, inline="always")
def spread(x):
    """The low 21 bits of ``x`` spread to every third bit."""
    x &= 0x1FFFFF
    x = (x | (x << 32)) & 0x1F00000000FFFF
    x = (x | (x << 16)) & 0x1F0000FF0000FF
    x = (x | (x << 8)) & 0x100F00F00F00F00F
    x = (x | (x << 4)) & 0x10C30C30C30C30C3
    x = (x | (x << 2)) & 0x1249249249249249
    return x


@numba.njit(cache=True, inline="always")
def code(ix, iy, iz):
    """The Morton code of integer cell coordinates (their low 21 bits)."""
    return spread(ix) | (spread(iy) << 1) | (spread(iz) << 2)


@numba.njit(cache=True)
def codes(V):
    """Morton codes of points ``V (n, 3)`` on a ``2^21`` grid over their bounding cube."""
    lo = np.empty(3)
    size = 0.0
    for c in range(3):
        lo[c] = V[:, c].min()
        size = max(size, V[:, c].max() - lo[c])
    s = (2**BITS - 1) / size if size > 0.0 else 0.0
    out = np.empty(V.shape[0], np.int64)
    for i in range(V.shape[0]):
        out[i] = code(np.int64((V[i, 0] - lo[0]) * s), np.int64((V[i, 1] - lo[1]) * s), np.int64((V[i, 2] - lo[2]) * s))
    return out

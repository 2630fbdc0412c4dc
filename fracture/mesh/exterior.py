"""Queries against the exterior surface B with libigl's trees built once.

``igl.fast_winding_number`` and ``igl.point_mesh_squared_distance`` rebuild
their hierarchy over B on every call; code that asks many times (bisection,
per-iteration projections, seed sampling) holds an :class:`Exterior` instead.
"""

from __future__ import annotations

from functools import cached_property

import igl
import numpy as np
from scipy import ndimage

from fracture.mesh.topology import face_frames


def fast_winding(V: np.ndarray, F: np.ndarray, P: np.ndarray) -> np.ndarray:
    """libigl's fast winding numbers at points ``P`` of the triangles ``(V, F)``, taken about the centre of
    ``V``'s box: its hierarchy holds single-precision coordinates, and about the origin an object far from
    it is off by up to a half (a cube at (1e5, -5e4, 0) took 12 of 2,000 points inside for outside).
    No triangles wind about no point (libigl reads memory it never wrote then, and may crash)."""
    if not len(F):
        return np.zeros(len(np.asarray(P).reshape(-1, 3)))
    V = np.asarray(V, np.float64)
    centre = _centre(V)
    return igl.fast_winding_number(np.ascontiguousarray(V - centre), np.ascontiguousarray(F, np.int64),
                                   np.ascontiguousarray(np.asarray(P, np.float64).reshape(-1, 3) - centre))


# A triangle is split for a grid's query while its box holds more than this many times the nodes near it
# (its area and its spans in cells: a slanted triangle; an axis-aligned one's box is a slab of two layers) ...
_BOX_OVER_AREA = 8.0
# ... and spans more than this many cells along an axis.
_PIECE_CELLS = 2.0


def _small_pieces(T: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """Triangles ``T`` (``(m, 3, 3)``: corners) split into four at their edges' midpoints, again and again,
    while their boxes on the grid of ``spacing`` hold many nodes far from them (:data:`_BOX_OVER_AREA`,
    :data:`_PIECE_CELLS`); their union is the union of ``T``."""
    out = []
    cell = float(np.prod(spacing)) ** (1.0 / 3.0)
    for _ in range(32):  # each round halves a piece's span: 32 rounds reach any span a float can hold
        span = (T.max(axis=1) - T.min(axis=1)) / spacing
        nodes = np.prod(np.floor(span) + 2.0, axis=1)
        area = 0.5 * np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1) / (cell * cell)
        big = (span.max(axis=1) > _PIECE_CELLS) & (nodes > _BOX_OVER_AREA * (area + span.sum(axis=1) + 1.0))
        out.append(T[~big])
        T = T[big]
        if not len(T):
            break
        a, b, c = T[:, 0], T[:, 1], T[:, 2]
        ab, bc, ca = 0.5 * (a + b), 0.5 * (b + c), 0.5 * (c + a)
        T = np.concatenate([np.stack(q, 1) for q in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    out.append(T)
    return np.concatenate(out)


def _centre(V: np.ndarray) -> np.ndarray:
    return 0.5 * (V.min(axis=0) + V.max(axis=0)) if len(V) else np.zeros(3)


class Exterior:
    """A closed triangle mesh with a winding-number hierarchy and an AABB tree, each built on its
    first query (the refinement asks only for closest points, and a hierarchy it never uses would
    cost it time: ``docs/design-measurements.md``)."""

    def __init__(self, V: np.ndarray, F: np.ndarray):
        self.V = np.ascontiguousarray(V, np.float64)
        self.F = np.ascontiguousarray(F, np.int64)

    @cached_property
    def _centre(self) -> np.ndarray:
        """The centre of B's box: winding numbers are taken about it, as :func:`fast_winding` takes them."""
        return _centre(self.V)

    @cached_property
    def _wn(self):
        wn = igl.FastWindingNumberBVH()
        wn.init(np.ascontiguousarray(self.V - self._centre), self.F)
        return wn

    @cached_property
    def _tree(self):
        tree = igl.AABB()
        tree.init(self.V, self.F)
        return tree

    @cached_property
    def normals(self) -> np.ndarray:
        """Unit outward normals of B's triangles, ``(m, 3)``."""
        return face_frames(self.V, self.F)[1]

    def normal_at(self, P: np.ndarray) -> np.ndarray:
        """Unit outward normals of B at the points of B closest to ``P``, ``(k, 3)``."""
        return self.normals[self.closest(P)[1]]

    def winding(self, P: np.ndarray) -> np.ndarray:
        """Winding numbers at points ``(k, 3)``: :func:`fast_winding`'s, from the hierarchy built once."""
        return self._wn.winding_number(np.ascontiguousarray(np.asarray(P, np.float64).reshape(-1, 3)
                                                            - self._centre))

    def inside(self, P: np.ndarray) -> np.ndarray:
        """Whether points are inside (winding number above one half)."""
        return self.winding(P) > 0.5

    def closest(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Squared distances, triangle ids and closest points on B of points ``(k, 3)``."""
        return self._tree.squared_distance(self.V, self.F, np.ascontiguousarray(P, np.float64).reshape(-1, 3))

    def distance(self, P: np.ndarray) -> np.ndarray:
        return np.sqrt(self.closest(P)[0])

    def grid_nodes(self, origin, spacing, shape, within: float, asked: np.ndarray | None = None,
                   near: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Which nodes of a grid (``origin``, ``spacing``, ``shape``) are inside B, and which lie within
        ``within`` (less than a cell) of B, both ``shape`` (the second None unless ``near``); only the
        nodes ``asked`` (a mask of ``shape``, default all) are answered, the others are False.

        Only the nodes of the cells that B's triangles' bounding boxes meet are
        asked (winding number and distance); every other node lies in a region
        of such nodes joined by grid edges that B does not cross (a triangle
        across an edge would have marked both its ends), so one winding number
        per region answers for all of it. On the collapsing wall's search band
        0.04 s against 0.40 s for asking every node. A triangle larger than a
        few cells is split first (:func:`_small_pieces`): the box of a large
        slanted one holds mostly nodes far from it (a prism's six faces marked
        every node of its grid)."""
        origin, spacing = np.asarray(origin, np.float64), np.asarray(spacing, np.float64)
        shape = tuple(int(n) for n in shape)
        T = _small_pieces(self.V[self.F], spacing)
        lo = np.floor((T.min(axis=1) - within - origin) / spacing).astype(np.int64)
        hi = np.floor((T.max(axis=1) + within - origin) / spacing).astype(np.int64) + 1  # the box's last node
        lo = np.clip(lo, 0, np.array(shape) - 1)
        hi = np.clip(hi, -1, np.array(shape) - 1)
        dims = np.maximum(hi - lo + 1, 0)
        count = np.prod(dims, axis=1)
        touched = np.zeros(shape, bool)
        if count.sum() > 16 * touched.size:  # B's boxes cover the grid many times over: ask every node
            touched[:] = True
        else:  # every node of every box, in batches of triangles of about the grid's size
            ends = np.cumsum(count)
            cuts = np.searchsorted(ends, np.arange(1, -(-int(count.sum()) // touched.size)) * touched.size)
            for batch in np.split(np.arange(len(T)), cuts):
                c = count[batch]
                t = np.repeat(batch, c)  # the k-th node of triangle t's box, z fastest
                k = np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c)
                nz, ny = dims[t, 2], dims[t, 1]
                touched[lo[t, 0] + k // (nz * ny), lo[t, 1] + (k // nz) % ny, lo[t, 2] + k % nz] = True
        asked = np.ones(shape, bool) if asked is None else np.asarray(asked, bool).reshape(shape)
        idx = np.flatnonzero(touched & asked)
        P = origin + np.stack(np.unravel_index(idx, shape), 1) * spacing
        inside = np.zeros(shape, bool)
        on_b = np.zeros(shape, bool) if near else None
        if len(idx):
            inside.flat[idx] = self.inside(P)
            if near:
                on_b.flat[idx] = self.closest(P)[0] < within * within
        regions, n = ndimage.label(~touched)
        if n:
            _, first = np.unique(regions.ravel(), return_index=True)  # a node of each region (0: the touched)
            seeds = origin + np.stack(np.unravel_index(first[1:], shape), 1) * spacing
            inside |= np.concatenate([[False], self.inside(seeds)])[regions] & asked
        return inside, on_b

    def along(self, start: np.ndarray, through: np.ndarray) -> np.ndarray:
        """Per row, where the ray from ``start`` (inside B) through ``through`` first meets B: a point of a
        fracture sheet put on B in the sheet's own plane (from a corner inside, through the point), which
        B's closest point is not near a crease (points on both sides of B's edge go to the edge, and two
        boundary curves there can cross). Rows whose ray meets nothing, or whose ``start`` is not inside,
        take B's closest point to ``through``."""
        start = np.ascontiguousarray(start, np.float64).reshape(-1, 3)
        through = np.ascontiguousarray(through, np.float64).reshape(-1, 3)
        ray = through - start
        target = through.copy()  # where B's closest point is taken: the ray's hit, or the point itself
        ok = self.inside(start) & (np.einsum("ij,ij->i", ray, ray) > 0.0)
        if ok.any():
            face, t, _ = self._tree.intersect_ray_first(self.V, self.F, start[ok], np.ascontiguousarray(ray[ok]))
            hit = (face >= 0) & np.isfinite(t) & (t > 0.0)
            rows = np.flatnonzero(ok)[hit]
            target[rows] = start[rows] + t[hit, None] * ray[rows]  # within rounding of B
        return self.closest(target)[2]

    def crossing(self, inner: np.ndarray, outer: np.ndarray) -> np.ndarray:
        """Per row, the fraction of the segment from ``inner`` to ``outer`` at which it first meets B (a ray
        cast through libigl's AABB tree); NaN where it meets B nowhere on the segment."""
        inner = np.ascontiguousarray(inner, np.float64).reshape(-1, 3)
        ray = np.ascontiguousarray(np.asarray(outer, np.float64).reshape(-1, 3) - inner)
        t = np.full(len(inner), np.nan)
        if not len(inner):
            return t
        face, hit, _ = self._tree.intersect_ray_first(self.V, self.F, inner, ray)
        ok = (face >= 0) & np.isfinite(hit) & (hit >= 0.0) & (hit <= 1.0)
        t[ok] = hit[ok]
        return t

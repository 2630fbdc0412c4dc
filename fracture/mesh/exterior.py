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

from fracture.mesh.topology import across_edges, face_frames, one_fan, split_while
from fracture.tolerances import tol


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


# A point's side of B is sure where its offset from its closest point makes more than this cosine with the
# plane of the closest point's pseudonormal (otherwise the winding number is asked).
_SURE_SIDE = 0.1


def _small_pieces(T: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """Triangles ``T`` (``(m, 3, 3)``: corners) split into four at their edges' midpoints, again and again,
    while their boxes on the grid of ``spacing`` hold many nodes far from them (:data:`_BOX_OVER_AREA`,
    :data:`_PIECE_CELLS`); their union is the union of ``T``."""
    cell = float(np.prod(spacing)) ** (1.0 / 3.0)

    def far_from_its_nodes(T):
        span = (T.max(axis=1) - T.min(axis=1)) / spacing
        nodes = np.prod(np.floor(span) + 2.0, axis=1)
        area = 0.5 * np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1) / (cell * cell)
        return (span.max(axis=1) > _PIECE_CELLS) & (nodes > _BOX_OVER_AREA * (area + span.sum(axis=1) + 1.0))

    return split_while(T, far_from_its_nodes)


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

    @cached_property
    def _across(self) -> np.ndarray | None:
        """:func:`across_edges` of B: None unless B is closed and oriented (the surfaces on which a closest
        point's pseudonormal tells inside from outside)."""
        return across_edges(self.F)

    @cached_property
    def _on_b(self) -> float:
        """Closer to B than this is on it, to rounding (:data:`tol.side_of_b` of its diagonal)."""
        return tol.side_of_b * float(np.linalg.norm(np.ptp(self.V, axis=0))) if len(self.V) else 0.0

    @cached_property
    def _corner_normals(self) -> np.ndarray:
        """Per vertex of a closed oriented B its angle-weighted normal; zero at a pinch (its triangles make
        more than one fan), where no normal tells."""
        normal = igl.per_vertex_normals(self.V, self.F, igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_ANGLE)
        normal[~one_fan(self.F, self._across, len(self.V))] = 0.0
        return np.nan_to_num(normal)

    def inside_near(self, P: np.ndarray, tri: np.ndarray, C: np.ndarray) -> np.ndarray:
        """:meth:`inside` for points ``P`` whose closest points ``C`` on B, on triangles ``tri``, are known
        (:meth:`closest`): the side of the closest point's pseudonormal (its triangle's normal, the sum of
        the two triangles' normals on an edge, the angle-weighted normal at a corner: Baerentzen and Aanaes,
        "Signed distance computation using the angle weighted pseudonormal", 2005), the winding number where
        that is not sure: a point on B (to rounding) or nearly level with the normal, a corner at a pinch of
        B, a B that is not closed.

        Winding numbers near B are the dearest to take (the hierarchy's far-field sums do not apply): on
        350,000 points within a cell or so of the scenes' B, 0.6-1.2 s against 0.08 s for this (with the
        closest points known)."""
        P = np.ascontiguousarray(P, np.float64).reshape(-1, 3)
        across = self._across
        if across is None or not len(P):
            return self.inside(P)
        tri = np.asarray(tri, np.int64)
        T = self.V[self.F[tri]]
        bary = igl.barycentric_coordinates(np.ascontiguousarray(C, np.float64),
                                           *(np.ascontiguousarray(T[:, k]) for k in range(3)))
        on = bary < tol.on_feature  # NaN (a triangle of no area) is on nothing: its normal is zero, and unsure
        count = on.sum(axis=1)
        normal = self.normals[tri].copy()
        edge = np.flatnonzero(count == 1)  # on the edge opposite the zero weight's corner j: edge j + 1
        normal[edge] += self.normals[across[tri[edge], (np.argmax(on[edge], axis=1) + 1) % 3]]
        vertex = np.flatnonzero(count == 2)  # at the corner of the nonzero weight
        if len(vertex):
            normal[vertex] = self._corner_normals[self.F[tri[vertex], np.argmin(on[vertex], axis=1)]]
        away = P - C
        side = np.einsum("ij,ij->i", away, normal)
        length = np.linalg.norm(away, axis=1)
        sure = (np.abs(side) > _SURE_SIDE * length * np.linalg.norm(normal, axis=1)) & (length > self._on_b)
        out = side < 0.0
        unsure = np.flatnonzero(~sure)
        if len(unsure):
            out[unsure] = self.inside(P[unsure])
        return out

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
        asked (closest point, and from it the side: :meth:`inside_near`); every other node lies in a region
        of such nodes joined by grid edges that B does not cross (a triangle
        across an edge would have marked both its ends), so one node per region
        answers for all of it. On the collapsing wall's search band 0.04 s
        against 0.40 s for asking every node. A triangle larger than a
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
            d2, tri, C = self.closest(P)
            inside.flat[idx] = self.inside_near(P, tri, C)
            if near:
                on_b.flat[idx] = d2 < within * within
        regions, n = ndimage.label(~touched)
        if n:
            _, first = np.unique(regions.ravel(), return_index=True)  # a node of each region (0: the touched)
            seeds = origin + np.stack(np.unravel_index(first[1:], shape), 1) * spacing
            inside |= np.concatenate([[False], self.inside_near(seeds, *self.closest(seeds)[1:])])[regions] & asked
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

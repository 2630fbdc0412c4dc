"""Adaptive fracture remeshing (Section 4.4): where to split, as a plan the engine applies.

One random sample per triangle, inside it, or on its boundary or junction
edge when it has one (the paper samples those edges so that the boundary and
the non-manifold junctions refine too). The sample is moved by Eq. 3 with its
triangle as its neighbourhood (:func:`fracture.refine.flow.sample_displacement`);
where it leaves the triangle by more than ``far`` in one nominal step (its
own move minus the move its corners give it: across the triangle's plane,
or for an edge sample across the edge) it becomes a vertex: a 1-to-3 split of
the triangle, or an edge split through every triangle on the edge.

The boundary must also stay on B: a long chord across a curved B leaves a
gap between the sheet and B through which the pieces on its two sides would
meet (the paper samples boundary edges "to refine the fracture surface
boundary"). :func:`plan_chord_splits` tests the middle of every boundary
edge for that, at the last stage's ``near`` whatever the stage: the boundary
follows B, not the field.

A sample leaves its triangle when grad psi's normal part at the sample
differs from what the corners carry, that is where psi varies across the
triangle: flat regions of psi keep their large triangles, and the budget
goes to valleys, grains and brick edges. The threshold ``far`` is absolute
(grid cells): a triangle stops splitting once the field is linear enough
across it, not once it is small. Samples closer than ``near`` to a corner are
skipped (the engine sets ``near`` per stage of its schedule: triangles need
not be finer than the field they follow), and so are:

* samples inside needles (their children would be needles too; the flips
  improve them first);
* any split beside a boundary vertex still off B (a collision stopped its
  projection): smaller triangles around it would fold when it moves onto B.

A triangle takes part in one split at most per round; the triangle budget
caps the round.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from fracture.refine.crossings_on_b import splits_would_cross
from fracture.refine.flow import sample_displacement
from fracture.mesh.edges import EdgeTable, first_per_group
from fracture.mesh import vec
from fracture.mesh.faces import face_geometry, unit_normal_into
from fracture.tolerances import tol

# compiled code reads tolerances as module constants (fracture/tolerances.py says why each)
_TINY = tol.tiny

# Samples inside a triangle keep every barycentric coordinate at least this
# (a sample near an edge would make a sliver); edge samples stay this far
# from the edge's ends, as a fraction of the edge.
_INSIDE, _ALONG = 0.1, 0.2
# Needles (quality below this, 1 for an equilateral triangle) are not split inside.
_MIN_QUALITY = 0.2


@dataclass
class SplitPlan:
    """The splits of one round.

    Attributes
    ----------
    edges : (k, 2) int
        Edges to split, each at ``(1 - t) a + t b``.
    t : (k,) float
    rows, which : (r,) int
        The directed triangle edges on the split edges and the split edge of each (for
        :meth:`~fracture.mesh.fracture_surface.FractureSurface.split_edges`).
    faces : (s,) int
        Triangles to split 1-to-3 at barycentric points ``bary (s, 3)``.
    full : bool
        The triangle budget left out a wanted split.
    """

    edges: np.ndarray
    t: np.ndarray
    rows: np.ndarray
    which: np.ndarray
    faces: np.ndarray
    bary: np.ndarray
    full: bool

    @property
    def count(self) -> int:
        return len(self.edges) + len(self.faces)

    def apply(self, mesh) -> int:
        """Split ``mesh`` (a :class:`~fracture.mesh.fracture_surface.FractureSurface`); returns the number of new vertices."""
        if len(self.edges):
            mesh.split_edges(self.edges, self.t, rows=self.rows, which=self.which)
        if len(self.faces):
            mesh.split_triangles(self.faces, self.bary)
        return self.count


def split_folds(T: np.ndarray, k: np.ndarray, Q: np.ndarray, N: np.ndarray) -> np.ndarray:
    """Whether splitting edge ``k`` of triangles ``T (s, 3, 3)`` (unit normals ``N``) at a vertex that
    then moves to ``Q`` turns one of the two new triangles over (its normal against its parent's)."""
    ar = np.arange(len(T))
    a, b, d = T[ar, k], T[ar, (k + 1) % 3], T[ar, (k + 2) % 3]
    n1, n2 = np.cross(Q - a, d - a), np.cross(b - Q, d - Q)
    return (np.einsum("ij,ij->i", n1, N) <= 0.0) | (np.einsum("ij,ij->i", n2, N) <= 0.0)


def plan_splits(V, F, table: EdgeTable, v, psi, tau, field, rng, *, near, far, budget, off_b,
                grain=None) -> SplitPlan:
    """The split plan of one round (module notes).

    Parameters
    ----------
    V, F, table : the surface and its edge table.
    v, psi : (n, 3), (n,)
        Velocity of Eq. 3 and the (shifted) psi the flow uses, at the vertices.
    tau : float
        The nominal step: a sample's move is ``tau`` times its velocity.
    field : callable
        ``field(P) -> (psi, grad psi)`` at points, as the flow uses them.
    rng : numpy.random.Generator
    near, far : float
        Samples within ``near`` of a corner are skipped; a split is wanted where a sample leaves its
        triangle by more than ``far``.
    budget : int
        Triangles that may still be made.
    off_b : (j,) int
        Boundary vertices still off B.
    """
    m = len(F)
    empty = SplitPlan(np.zeros((0, 2), np.int64), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64),
                      np.zeros(0, np.int64), np.zeros((0, 3)), budget <= 0)
    if budget <= 0 or m == 0:
        return empty
    row_count = table.row_count
    special = (row_count != 2).reshape(-1, 3)  # boundary or junction edges of every triangle
    has_edge = special.any(axis=1)
    k_edge = np.argmax(special * rng.random((m, 3)), axis=1)  # one of its special edges, at random
    T = V[F]
    bary = _INSIDE + (1.0 - 3.0 * _INSIDE) * rng.dirichlet([1.0, 1.0, 1.0], size=m)
    t = rng.uniform(_ALONG, 1.0 - _ALONG, size=m)
    rows = np.flatnonzero(has_edge)
    bary[rows] = 0.0
    bary[rows, k_edge[rows]] = 1.0 - t[rows]
    bary[rows, (k_edge[rows] + 1) % 3] = t[rows]
    P = np.einsum("fk,fkc->fc", bary, T)
    psi_P, grad_P = field(P)
    d = sample_displacement(P, T, psi_P, grad_P, psi[F], tau, grain)
    want, _ = split_wanted(T, P, bary, d, v, F, tau, k_edge, has_edge, near * near, far, _MIN_QUALITY)
    beside = None
    if len(off_b):
        off = np.zeros(len(V), bool)
        off[off_b] = True
        beside = off[F].any(axis=1)
        want &= ~beside
    budget = budget // 2  # a split makes at least two triangles
    full = False
    # edge splits: one per edge (a random one of its triangles' samples) ...
    ef = np.flatnonzero(want & has_edge)
    eid = table.eid[3 * ef + k_edge[ef]]
    keep = first_per_group(eid, rng.random(len(ef)))
    ef, eid = ef[keep], eid[keep]
    # ... and a triangle takes part in one split at most: of two chosen
    # edges on a triangle, the later one is dropped everywhere
    good = table.independent(eid)
    full |= int(good.sum()) > budget
    good &= np.cumsum(good) <= budget
    ef, eid = ef[good], eid[good]
    on, which = table.rows_of(eid)
    if beside is not None and len(eid):  # ... nor a junction edge with a triangle beside an off-B vertex
        clear = np.bincount(which, weights=beside[on // 3], minlength=len(eid)) == 0
        kept = clear[which]
        ef, eid, on, which = ef[clear], eid[clear], on[kept], (np.cumsum(clear) - 1)[which[kept]]
    busy = np.zeros(m, bool)
    busy[on // 3] = True
    E = np.stack([F[ef, k_edge[ef]], F[ef, (k_edge[ef] + 1) % 3]], 1).reshape(-1, 2)
    # 1-to-3 splits of the others
    tf = np.flatnonzero(want & ~has_edge & ~busy)
    room = max(0, budget - len(ef))
    full |= len(tf) > room
    tf = tf[:room]
    return SplitPlan(E, t[ef], on, which, tf, bary[tf], full)


def plan_chord_splits(V, F, table: EdgeTable, *, far, near_b, budget, project, off_b, normal_at=None) -> SplitPlan:
    """Splits at the middle of every boundary edge whose chord passes farther than ``far`` from B.

    Every boundary edge is tested at once (a random sample per edge finds a
    long chord across a crease of B only over several rounds, while the
    boundary slides on B in steps of a grid cell), so the pieces on the two
    sides of a sheet do not meet through the gap. Edges shorter
    than ``2 near_b`` and splits whose projection would turn a new triangle
    over are left alone, and so are edges on a vertex still off B (``off_b``:
    a collision stopped its projection; its chords are off B with it), and,
    given B's normals (``normal_at``), splits whose new vertex on B would make
    the boundary cross another boundary curve there
    (:func:`~fracture.refine.crossings_on_b.splits_would_cross`).
    """
    rows = table.boundary_rows
    none = SplitPlan(np.zeros((0, 2), np.int64), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64),
                     np.zeros(0, np.int64), np.zeros((0, 3)), budget <= 0)
    if budget <= 0 or not len(rows):
        return none
    f, k = rows // 3, rows % 3
    T = V[F[f]]
    a, b = T[np.arange(len(f)), k], T[np.arange(len(f)), (k + 1) % 3]
    P = 0.5 * (a + b)
    Q = project(P)
    N = face_geometry(V, F[f])[1]
    want = (np.linalg.norm(Q - P, axis=1) > far) & (np.linalg.norm(b - a, axis=1) >= 2.0 * near_b)
    want &= ~split_folds(T, k, Q, N)
    if len(off_b):
        off = np.zeros(len(V), bool)
        off[off_b] = True
        want &= ~(off[F[f, k]] | off[F[f, (k + 1) % 3]])
    if normal_at is not None and want.any():
        Eall = np.stack([F[f, k], F[f, (k + 1) % 3]], 1)
        idx = np.flatnonzero(want)
        want[idx[splits_would_cross(V, Eall, idx, Q[idx], normal_at)]] = False
    rows = rows[want]
    eid = table.eid[rows]
    good = table.independent(eid)
    good &= np.cumsum(good) <= budget // 2
    rows, eid = rows[good], eid[good]
    on, which = table.rows_of(eid)
    E = np.stack([F[rows // 3, rows % 3], F[rows // 3, (rows % 3 + 1) % 3]], 1).reshape(-1, 2)
    return SplitPlan(E, np.full(len(E), 0.5), on, which, np.zeros(0, np.int64), np.zeros((0, 3)), False)


@numba.njit(cache=True)
def split_wanted(T, P, bary, d, v, F, dt, k_edge, has_edge, near2, far, min_quality):
    """Which samples ask for a split (module notes), and the unit
    normals of the triangles ``T (m, 3, 3)``.

    A sample ``P[f] = bary[f] . T[f]`` moving by ``d[f]`` leaves its triangle by its move minus the
    move its corners (velocities ``v``, step ``dt``) give it: across the triangle's plane, or for a
    sample on edge ``k_edge[f]`` (``has_edge``) across that edge. It asks for a split when that is
    more than ``far``, it is not within ``sqrt(near2)`` of a corner, and a sample inside a triangle
    lies in one of quality above ``min_quality`` (1 for an equilateral triangle).
    """
    m = T.shape[0]
    want = np.zeros(m, np.bool_)
    N = np.zeros((m, 3))
    q = 4.0 * np.sqrt(3.0)
    for f in range(m):
        near = np.inf
        for k in range(3):
            r = vec.sub(vec.point(T[f], k), vec.point(P, f))
            near = min(near, vec.dot(r, r))
        o = vec.point(T[f], 0)
        t = unit_normal_into(vec.sub(vec.point(T[f], 1), o), vec.sub(vec.point(T[f], 2), o), N, f)
        if near < near2:
            continue
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        dx = d[f, 0] - (bary[f, 0] * (dt * v[a, 0]) + bary[f, 1] * (dt * v[b, 0]) + bary[f, 2] * (dt * v[c, 0]))
        dy = d[f, 1] - (bary[f, 0] * (dt * v[a, 1]) + bary[f, 1] * (dt * v[b, 1]) + bary[f, 2] * (dt * v[c, 1]))
        dz = d[f, 2] - (bary[f, 0] * (dt * v[a, 2]) + bary[f, 1] * (dt * v[b, 2]) + bary[f, 2] * (dt * v[c, 2]))
        if has_edge[f]:
            k = k_edge[f]
            j = (k + 1) % 3
            ex, ey, ez = T[f, j, 0] - T[f, k, 0], T[f, j, 1] - T[f, k, 1], T[f, j, 2] - T[f, k, 2]
            length = max(np.sqrt(ex * ex + ey * ey + ez * ez), _TINY)
            ex, ey, ez = ex / length, ey / length, ez / length
            along = dx * ex + dy * ey + dz * ez
            ax, ay, az = dx - along * ex, dy - along * ey, dz - along * ez
            want[f] = np.sqrt(ax * ax + ay * ay + az * az) > far
        else:
            sq = 0.0
            for k in range(3):
                i = (k + 2) % 3
                r = vec.sub(vec.point(T[f], k), vec.point(T[f], i))
                sq += vec.dot(r, r)
            want[f] = (abs(dx * N[f, 0] + dy * N[f, 1] + dz * N[f, 2]) > far
                       and q * 0.5 * t / max(sq, _TINY) > min_quality)
    return want, N


class PsiSplits:
    """The paper's split rule (module notes): a triangle is split where a sample point of it, moved by the
    flow, would leave it. What the refiner asks of a split rule: ``plan(refiner, table, v, w, budget)``,
    the :class:`SplitPlan` of one round from the surface (``refiner.mesh``), its edge table, the velocity
    and integrand at the vertices and the triangles that may still be made."""


    def plan(self, refiner, table: EdgeTable, v: np.ndarray, w: np.ndarray, budget: int) -> SplitPlan:
        m = refiner.mesh
        return plan_splits(m.V, m.F, table, v, w, refiner.step.start, refiner.field, refiner.rng, near=refiner.near,
                           far=refiner.params.split_distance * refiner.h, off_b=refiner.onb.off_b, grain=refiner.grain,
                           budget=budget)


class LongEdgeSplits:
    """A second split rule: every edge longer than ``length`` is halved, whatever the field (uniform
    refinement), at most one edge per triangle a round (the longest first), within the budget."""


    def __init__(self, length: float):
        self.length = float(length)

    def plan(self, refiner, table: EdgeTable, v: np.ndarray, w: np.ndarray, budget: int) -> SplitPlan:
        V, F = refiner.mesh.V, refiner.mesh.F
        rows = table.first[table.first >= 0]  # one directed triangle edge per edge
        E = np.stack([F[rows // 3, rows % 3], F[rows // 3, (rows % 3 + 1) % 3]], 1)
        length = np.linalg.norm(V[E[:, 1]] - V[E[:, 0]], axis=1)
        order = np.argsort(-length, kind="stable")
        order = order[length[order] > self.length]
        order = order[table.independent(table.eid[rows[order]])]  # no triangle carries two
        adds = table.count[table.eid[rows[order]]]  # a split edge adds a triangle per triangle on it
        keep = np.cumsum(adds) <= budget
        chosen = order[keep]
        on, which = table.rows_of(table.eid[rows[chosen]])
        return SplitPlan(E[chosen], np.full(len(chosen), 0.5), on, which, np.zeros(0, np.int64), np.zeros((0, 3)),
                         not keep.all())

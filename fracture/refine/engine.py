"""The refinement loop: gradient flow, boundary constraint and adaptive splits (Sections 4.3, 4.4).

One iteration:

1. psi and the level-averaged grad psi at every vertex (one interpolation);
2. the velocity of Eq. 3 (:mod:`fracture.refine.flow`) and the step: ``dt``
   moves a vertex of median speed ``step`` grid cells (speeds below a floor
   count as rest), and no vertex moves more than ``max_move`` of its shortest
   edge or one grid cell: explicit steps stay stable because no vertex can
   overtake its neighbours; an iteration that raises the energy halves the
   following steps (overshoot at the bottom of a valley of psi), and they
   grow back by 20 % per iteration that lowers it; boundary vertices move
   tangentially to B;
3. boundary vertices are projected back onto the exterior B;
4. one random sample per triangle (on its boundary or junction edge when it
   has one) is moved by Eq. 3 with the triangle as its neighbourhood; where it
   leaves the triangle by more than ``split_distance`` grid cells, it becomes
   a vertex (1-to-3 split, or an edge split through every triangle on the
   edge). Samples closer than ``min_edge`` grid cells to a corner are skipped.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fracture.exterior import Exterior
from fracture.refine.flips import flip_edges
from fracture.refine.flow import energy, sample_displacement, velocity
from fracture.refine.mesh import RefineMesh
from fracture.topology import boundary_conormals, directed_edges, edge_table, face_frames


@dataclass
class RefineParams:
    iterations: int = 40
    tolerance: float = 0.01  # stop when the mean vertex move is below this many grid cells
    step: float = 0.25
    max_move: float = 0.3
    split_distance: float = 0.2  # split when a sample leaves its triangle by this fraction of the step
    tension: float = 0.05  # psi is shifted so its minimum is this fraction of its range
    min_edge: float = 0.5
    max_triangles: int = 200_000


@dataclass
class IterationLog:
    energy: list = field(default_factory=list)
    mean_move: list = field(default_factory=list)
    triangles: list = field(default_factory=list)
    boundary_error: list = field(default_factory=list)


def _first_per_group(key: np.ndarray, rank: np.ndarray) -> np.ndarray:
    """Mask of the lowest-``rank`` entry of each ``key`` group."""
    if not len(key):
        return np.zeros(0, bool)
    order = np.lexsort((rank, key))
    first = np.r_[True, key[order][1:] != key[order][:-1]]
    mask = np.zeros(len(key), bool)
    mask[order[first]] = True
    return mask


class Refiner:
    """Evolves and refines a fracture surface toward low psi."""

    def __init__(self, mesh: RefineMesh, pyramid, BV: np.ndarray, BF: np.ndarray, params: RefineParams,
                 rng: np.random.Generator):
        self.mesh, self.pyramid, self.params, self.rng = mesh, pyramid, params, rng
        self.BV = np.ascontiguousarray(BV, np.float64)
        self.BF = np.ascontiguousarray(BF, np.int64)
        self.h = float(np.min(pyramid.grid.spacing))
        self.log = IterationLog()
        # A negative psi would reward area: the flow would wrinkle without
        # bound and explicit steps would be anti-diffusive. Shifting psi adds
        # a constant surface tension and leaves grad psi unchanged.
        values = pyramid.levels[0]
        self.offset = params.tension * float(np.ptp(values)) - float(values.min())
        self.free_d = np.zeros_like(mesh.V)
        self.scale = 1.0  # halved when an iteration raises the energy (overshoot), regrown after
        self.B_normals = face_frames(self.BV, self.BF)[1]
        self.B = Exterior(self.BV, self.BF)  # trees built once: every iteration queries them
        # speeds below this (psi changing by 1 % of its range per grid cell)
        # count as at rest: dt stops growing, the moves shrink, the loop ends
        self.slow = 0.01 * float(np.ptp(values)) / self.h

    def field(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        psi, grad = self.pyramid.value_and_gradient(P)
        return psi + self.offset, grad

    # -- topology ---------------------------------------------------------------------------
    def edges(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Directed triangle edges (row ``3 f + k``), their undirected keys and triangle counts.

        Computed once per change of the triangles and shared by the step, the
        boundary constraint and the splits of an iteration.
        """
        D = directed_edges(self.mesh.F)
        key, count = edge_table(self.mesh.F, len(self.mesh.V))
        return D, key, count

    def boundary_vertices(self) -> np.ndarray:
        D, _, count = self.edges()
        return np.unique(D[count == 1])

    # -- constraints -----------------------------------------------------------------------

    def project_to_exterior(self, ids: np.ndarray) -> float:
        """Put vertices ``ids`` on B; returns the largest distance they had."""
        if not len(ids):
            return 0.0
        d2, _, C = self.B.closest(self.mesh.V[ids])
        self.mesh.V[ids] = C
        return float(np.sqrt(d2.max()))

    # -- one iteration --------------------------------------------------------------------
    def step(self) -> float:
        """Move the vertices by Eq. 3; returns the mean move in grid cells."""
        m, p = self.mesh, self.params
        self.topology = D, _, count = self.edges()
        psi, grad = self.field(m.V)
        v = velocity(m.V, m.F, psi, grad)
        # boundary vertices slide on B: drop the part of their velocity that
        # points out of the sheet across its boundary (the area term of an
        # open sheet pulls its boundary inward; at a crease of B this pull is
        # not normal to B) and the part normal to B (projection undoes it)
        E = D[count == 1]  # boundary edges, as oriented in their triangle
        self.boundary = np.zeros(0, np.int64)
        if len(E):
            b, c = boundary_conormals(m.V, m.F, E, strict=False)
            self.boundary = b
            v[b] -= np.einsum("ij,ij->i", v[b], c)[:, None] * c
            _, tri, _ = self.B.closest(m.V[b])
            nb = self.B_normals[tri]
            v[b] -= np.einsum("ij,ij->i", v[b], nb)[:, None] * nb
        speed = np.linalg.norm(v, axis=1)
        used = np.zeros(len(m.V), bool)
        used[m.F.ravel()] = True
        typical = max(float(np.median(speed[used])) if used.any() else 0.0, self.slow)
        self.dt = self.scale * p.step * self.h / typical
        d = self.dt * v
        self.free_d = d.copy()  # the unlimited moves, against which samples are compared
        # no vertex moves more than max_move of its shortest edge, nor more than a grid cell
        length = np.linalg.norm(m.V[D[:, 1]] - m.V[D[:, 0]], axis=1)
        shortest = np.full(len(m.V), np.inf)
        np.minimum.at(shortest, D[:, 0], length)
        np.minimum.at(shortest, D[:, 1], length)
        move = np.linalg.norm(d, axis=1)
        limit = np.minimum(p.max_move * shortest, self.h)
        d *= np.minimum(1.0, limit / np.maximum(move, 1e-300))[:, None]
        m.V += d
        return float(np.linalg.norm(d[used], axis=1).mean() / self.h)

    def remesh(self) -> int:
        """One round of sampled splits; returns the number of new vertices."""
        m, p = self.mesh, self.params
        if len(m.F) >= p.max_triangles:
            return 0
        _, key, count = self.topology  # the step did not change the triangles
        special = (count != 2).reshape(-1, 3)  # boundary or junction edges of every triangle
        has_edge = special.any(axis=1)
        k_edge = np.argmax(special, axis=1)
        T = m.V[m.F]
        # samples: random inside, or on the triangle's first special edge
        bary = self.rng.dirichlet([1.0, 1.0, 1.0], size=len(m.F))
        t = self.rng.uniform(0.2, 0.8, size=len(m.F))
        rows = np.flatnonzero(has_edge)
        bary[rows] = 0.0
        bary[rows, k_edge[rows]] = 1.0 - t[rows]
        bary[rows, (k_edge[rows] + 1) % 3] = t[rows]
        P = np.einsum("fk,fkc->fc", bary, T)
        # too close to a corner: skip
        near = np.linalg.norm(T - P[:, None, :], axis=2).min(axis=1) < p.min_edge * self.h
        psi_P, grad_P = self.field(P)
        psi_T = self.field(m.V)[0][m.F]
        # how far the sample leaves its triangle: its own move minus the move
        # the triangle's corners give it by linear interpolation
        d = sample_displacement(P, T, psi_P, grad_P, psi_T, self.dt)
        d -= np.einsum("fk,fkc->fc", bary, self.free_d[m.F])
        _, N = face_frames(m.V, m.F)
        off = np.abs(np.einsum("ij,ij->i", d, N))
        e = T[np.arange(len(m.F)), (k_edge + 1) % 3] - T[np.arange(len(m.F)), k_edge]
        e /= np.maximum(np.linalg.norm(e, axis=1), 1e-300)[:, None]
        across = np.linalg.norm(d - np.einsum("ij,ij->i", d, e)[:, None] * e, axis=1)
        far = np.where(has_edge, across, off) > p.split_distance * p.step * self.h
        want = far & ~near
        budget = max(0, (p.max_triangles - len(m.F)) // 2)
        # edge splits: one per edge, and a triangle takes part in one split at most
        ef = np.flatnonzero(want & has_edge)
        ekey = key[3 * ef + k_edge[ef]]
        keep = _first_per_group(ekey, self.rng.random(len(ef)))
        ef, ekey = ef[keep], ekey[keep]
        # all triangles on each chosen edge
        on = np.isin(key, ekey)
        tri_of = np.flatnonzero(on) // 3
        key_of = key[on]
        # drop edges whose triangles carry another chosen edge: keep, per triangle, one edge
        rank = np.searchsorted(np.sort(ekey), key_of)
        ok_tri = _first_per_group(tri_of, rank)
        bad_keys = np.unique(key_of[~ok_tri])
        good = ~np.isin(ekey, bad_keys)
        ef, ekey = ef[good], ekey[good]
        ef, ekey = ef[: budget], ekey[: budget]
        busy = np.zeros(len(m.F), bool)
        busy[tri_of[np.isin(key_of, ekey)]] = True
        a = m.F[ef, k_edge[ef]]
        b = m.F[ef, (k_edge[ef] + 1) % 3]
        new_edge = m.split_edges(np.stack([a, b], 1), t[ef]) if len(ef) else np.zeros(0, np.int64)
        # 1-to-3 splits of the others
        tf = np.flatnonzero(want & ~has_edge & ~busy)[: max(0, budget - len(ef))]
        if len(tf):
            m.split_triangles(tf, bary[tf])
        # new vertices on boundary edges lie on B
        boundary_new = new_edge[count[3 * ef + k_edge[ef]] == 1] if len(ef) else new_edge
        self.project_to_exterior(boundary_new)
        return len(new_edge) + len(tf)

    def run(self, callback=None) -> IterationLog:
        p = self.params
        for it in range(p.iterations):
            move = self.step()
            err = self.project_to_exterior(self.boundary)
            if move > 0:
                self.remesh()
            flip_edges(self.mesh.V, self.mesh.F, self.mesh.sides, max_passes=3)
            psi = self.pyramid.value(self.mesh.V)  # E(S) of the unshifted psi
            E = energy(self.mesh.V, self.mesh.F, psi)
            if self.log.energy and E > self.log.energy[-1]:
                self.scale *= 0.5
            else:
                self.scale = min(1.0, 1.2 * self.scale)
            self.log.energy.append(E)
            self.log.mean_move.append(move)
            self.log.triangles.append(len(self.mesh.F))
            self.log.boundary_error.append(err)
            if callback is not None:
                callback(it, self)
            if move < p.tolerance:
                break
        return self.log

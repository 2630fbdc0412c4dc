"""Components of an object cut by a fracture surface: volumetric flood fill (Section 4.1).

The object's inside (winding number of B) is sampled on a voxel grid; voxels
whose centre lies within ``0.6 h`` of the fracture surface are walls. Two
6-neighbours both farther than ``h / 2`` from the surface cannot be separated
by it (a crossing point would be within ``h / 2`` of one of them), so the
connected regions of the free voxels (scipy.ndimage.label) are exactly the
components at the grid's resolution. Each fracture triangle then reads the
component on either side a little away from its plane, and each exterior
triangle the component just inside it.
"""

from __future__ import annotations

import igl
import numpy as np
from scipy import ndimage

from fracture.errors import InputError
from fracture.coarse.surface import flood_fill_patches
from fracture.mesh.exterior import Exterior
from fracture.tolerances import tol
from fracture.mesh.topology import (boundary_edges, diagonal, directed_edges, edge_keys, edge_outward, face_frames,
                               unique_edges)

# Voxels with fewer free cells than this are slivers between the surface and
# B, not components.
_MIN_VOXELS = 8


def _face_samples(V, F):
    """Four points per triangle (centroid and halfway to each corner), ``(m, 4, 3)``, and unit normals."""
    T = V[F]
    centroid = T.mean(axis=1)
    samples = np.concatenate([centroid[:, None], centroid[:, None] + 0.5 * (T - centroid[:, None])], axis=1)
    return samples, face_frames(V, F)[1]


class _Lookup:
    """Labels of the voxel centres around points, on one side of a plane."""

    def __init__(self, labels, origin, h):
        self.labels, self.origin, self.h = labels, origin, h
        self.corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])

    def __call__(self, P, base=None, normal=None):
        """Labels ``(..., 8)`` of the 8 voxel centres around each point of ``P (..., 3)``.

        With ``base`` and ``normal``, centres not clearly in front of the
        plane through ``base`` (more than ``h / 4``) read 0.
        """
        f = (P - self.origin) / self.h
        idx = np.floor(f).astype(np.int64)[..., None, :] + self.corners  # (..., 8, 3)
        shape = np.array(self.labels.shape)
        ok = ((idx >= 0) & (idx < shape)).all(axis=-1)
        out = np.zeros(idx.shape[:-1], np.int64)
        out[ok] = self.labels[tuple(idx[ok].T)]
        if base is not None:
            C = self.origin + idx * self.h
            ahead = np.einsum("...kc,...c->...k", C - base[..., None, :], normal) > 0.25 * self.h
            out[~ahead] = 0
        return out


def _vote(lookup, samples, n, h, sign, distances=(0.8,), result=None) -> np.ndarray:
    """Most frequent non-zero label at ``samples + sign * d * n`` for growing ``d``; 0 if none.

    Only rows of ``result`` that are still 0 are looked up.
    """
    result = np.zeros(len(samples), np.int64) if result is None else result.copy()
    todo = result == 0
    for d in distances:
        if not todo.any():
            break
        nrm = sign * n[todo][:, None, :] * np.ones((1, samples.shape[1], 1))
        lab = np.maximum(lookup(samples[todo] + d * h * nrm, samples[todo], nrm).reshape(int(todo.sum()), -1), 0)
        # per row, the count of every label (one bincount for all rows); label 0 (none) is not a vote
        r, k = lab.shape[0], int(lab.max()) + 1 if lab.size else 1
        counts = np.bincount((np.arange(r)[:, None] * k + lab).ravel(), minlength=r * k).reshape(r, k)[:, 1:]
        voted = counts.max(axis=1, initial=0) > 0
        if voted.any():
            result[np.flatnonzero(todo)[voted]] = counts[voted].argmax(axis=1) + 1
        todo = result == 0
    return result


def _with_skirt(BV, BF, V, F, h):
    """The surface with a strip beyond each boundary edge that lies on B.

    Coarse boundary edges are chords of a curved B, so a thin gap can remain
    between the cut and B; the strip (outside B, in the plane of the edge's
    triangle) closes it for the flood fill.
    """
    E = boundary_edges(F)
    if not len(E):
        return V, F
    mid = 0.5 * (V[E[:, 0]] + V[E[:, 1]])
    gap = np.sqrt(igl.point_mesh_squared_distance(mid, BV, BF)[0])
    d = edge_outward(V, F, E, strict=False) * (1.2 * gap + 2.0 * h)[:, None]
    n = len(V)
    W = np.concatenate([V, V[E[:, 0]] + d, V[E[:, 1]] + d])
    k = np.arange(len(E))
    skirt = np.concatenate([np.stack([E[:, 1], E[:, 0], n + k], 1), np.stack([E[:, 1], n + k, n + len(E) + k], 1)])
    return W, np.concatenate([F, skirt])


def _fill_from_neighbours(F: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Give triangles without labels (rows with a 0) those of a labelled neighbour.

    Neighbours share an edge in opposite directions and no third triangle
    uses it, so they lie on the same sheet with the same orientation.
    """
    labels = labels.copy()
    missing = (labels == 0).any(axis=1)
    if not missing.any():
        return labels
    D = directed_edges(F)
    key = edge_keys(D, int(F.max()) + 1)
    order = np.argsort(key, kind="stable")
    k = key[order]
    first = np.r_[True, k[1:] != k[:-1]]
    group = np.cumsum(first) - 1
    size = np.bincount(group)
    pair = size[group] == 2
    i = np.flatnonzero(pair & first)  # first of the two directed edges of each manifold edge
    ea, eb = order[i], order[i + 1]
    opposite = D[ea, 0] == D[eb, 1]
    a, b = ea[opposite] // 3, eb[opposite] // 3
    for _ in range(len(F)):
        ma, mb = (labels[a] == 0).any(axis=1), (labels[b] == 0).any(axis=1)
        take_a, take_b = ma & ~mb, mb & ~ma
        if not (take_a.any() or take_b.any()):
            break
        labels[a[take_a]] = labels[b[take_a]]
        labels[b[take_b]] = labels[a[take_b]]
    return labels


def _patch_majority(V: np.ndarray, F: np.ndarray, sides: np.ndarray) -> np.ndarray:
    """One pair of components per patch between junction and boundary edges (area-weighted vote).

    A patch of a fracture surface separates the same two components
    everywhere, so isolated misreadings (a vote that reached past a nearby
    sheet at a sharp junction) are outvoted by the rest of the patch.
    """
    edges, count = unique_edges(F)
    patch = flood_fill_patches(F, edges[count != 2])
    area = face_frames(V, F)[0]
    known = (sides > 0).all(axis=1)
    if not known.any():
        return sides.copy()
    C = int(sides.max()) + 1
    # area per (patch, side pair), then the heaviest pair of every patch
    group, inv = np.unique(patch[known] * C * C + sides[known, 0] * C + sides[known, 1], return_inverse=True)
    weight = np.bincount(inv, area[known])
    gpatch = group // (C * C)
    order = np.lexsort((-weight, gpatch))
    first = order[np.r_[True, gpatch[order][1:] != gpatch[order][:-1]]]
    best = np.full(int(patch.max()) + 1, -1, np.int64)
    best[gpatch[first]] = group[first] % (C * C)
    out = sides.copy()
    has = best[patch] >= 0
    out[has] = np.stack([best[patch[has]] // C, best[patch[has]] % C], 1)
    return out


def _fill_around_junctions(V: np.ndarray, F: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Labels of unlabelled triangle sides from the wedges around their junction edges.

    Around an edge shared by several triangles, the space between two
    triangles that follow each other in angle is one component: a side of a
    triangle facing the next triangle around the edge has the component of
    that triangle's side facing back.
    """
    labels = labels.copy()
    key = edge_keys(directed_edges(F), len(V))
    n = face_frames(V, F)[1]
    for f in np.flatnonzero((labels == 0).any(axis=1)):
        for k in range(3):
            a, b = F[f, k], F[f, (k + 1) % 3]
            around = np.flatnonzero(key == key[3 * f + k]) // 3
            if len(around) < 3:
                continue
            axis = V[b] - V[a]
            axis /= np.linalg.norm(axis)

            def direction(g):
                d = V[F[g].sum() - a - b] - V[a]  # toward g's third corner
                d -= (d @ axis) * axis
                return d / np.linalg.norm(d)

            df = direction(f)
            turn = np.sign(n[f] @ np.cross(axis, df))  # rotating d_f toward +n_f
            others = around[around != f]
            dirs = np.array([direction(g) for g in others])
            angle = np.mod(turn * np.arctan2(np.cross(axis, df) @ dirs.T, dirs @ df), 2 * np.pi)
            for side, g in ((1, others[np.argmin(angle)]), (0, others[np.argmax(angle)])):
                if labels[f, side] == 0:
                    facing = 1 if n[g] @ df > 0 else 0  # the side of g that faces the wedge
                    labels[f, side] = labels[g, facing]
    return labels


def _near_surface(ids: np.ndarray, shape, origin: np.ndarray, h: float, V: np.ndarray, F: np.ndarray,
                  reach: float, stride: int = 4) -> np.ndarray:
    """The grid nodes ``ids`` (flat indices of a grid of spacing ``h``) closer than ``reach`` to the surface
    ``(V, F)``, exactly.

    Asking libigl's AABB tree about every node costs most of the labelling on
    fine grids; the surface is near few of them. So the distances are first taken on the nodes of every ``stride``-th
    grid line: a node is within ``stride sqrt(3) / 2`` voxels of one of them,
    and by the triangle inequality only nodes whose coarse neighbour is within
    ``reach`` plus that (and a voxel to spare) can be within ``reach``. Those
    are asked exactly.
    """
    ijk = np.stack(np.unravel_index(ids, tuple(shape)), 1)
    coarse_shape = np.asarray(shape) // stride + 1
    c = np.minimum(np.rint(ijk / stride).astype(np.int64), coarse_shape - 1)
    axes = [origin[k] + h * stride * np.arange(coarse_shape[k]) for k in range(3)]
    Q = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    dq = np.sqrt(igl.point_mesh_squared_distance(Q, V, F)[0]).reshape(tuple(coarse_shape))
    bound = reach + h * (0.5 * stride * np.sqrt(3.0) + 1.0)
    maybe = ids[dq[c[:, 0], c[:, 1], c[:, 2]] < bound]
    if not len(maybe):
        return maybe
    P = origin + h * np.stack(np.unravel_index(maybe, tuple(shape)), 1)
    d2 = igl.point_mesh_squared_distance(P, V, F)[0]
    return maybe[d2 < reach ** 2]


def label_components(BV: np.ndarray, BF: np.ndarray, V: np.ndarray, F: np.ndarray, resolution: int = 96,
                     what: str = "fracture surface", strict: bool = True) -> tuple[np.ndarray, np.ndarray, int]:
    """Components of the inside of B separated by the fracture surface ``(V, F)``.

    Parameters
    ----------
    BV, BF : closed, outward exterior surface.
    V, F : fracture surface.
    resolution : int
        Voxels along the longest side of B's box.
    strict : bool
        Raise when a fracture triangle has the same component on both sides;
        otherwise return such triangles with equal sides (for a caller that
        judges them, e.g. triangles smaller than a voxel).

    Returns
    -------
    sides : (m, 2) int
        Component behind and in front of each fracture triangle.
    exterior_component : (len(BF),) int
        Component of each exterior triangle.
    n_components : int
        Components are numbered by their lowest voxel (x-major order).

    Raises
    ------
    InputError
        When a fracture triangle has the same component on both sides (the
        surface does not separate the object there) or a side is not found.
    """
    BV = np.ascontiguousarray(BV, np.float64)
    BF = np.ascontiguousarray(BF, np.int64)
    V = np.ascontiguousarray(V, np.float64)
    F = np.ascontiguousarray(F, np.int64)
    lo, hi = BV.min(axis=0), BV.max(axis=0)
    h = float((hi - lo).max()) / resolution
    origin = lo - h
    shape = np.ceil((hi - lo) / h).astype(int) + 3
    # winding numbers asked near B and once per region of the nodes away from it (Exterior.grid_nodes): the
    # same answers as asking every node, which took 0.7-1.4 s of a small object's import
    inside = Exterior(BV, BF).grid_nodes(origin, h, shape, 0.0, near=False)[0].ravel()
    free = inside.copy()
    WV, WF = _with_skirt(BV, BF, V, F, h)
    near = _near_surface(np.flatnonzero(inside), shape, origin, h, WV, WF, 0.6 * h)
    free[near] = False
    labels, count = ndimage.label(free.reshape(shape))
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    keep = np.flatnonzero(sizes >= _MIN_VOXELS)
    keep = keep[keep > 0]
    remap = np.zeros(count + 1, np.int64)
    remap[keep] = np.arange(1, len(keep) + 1)
    lookup = _Lookup(remap[labels], origin, h)

    # read each side just off the triangle; where that is a wall (slivers,
    # junctions), take the label of a neighbour on the same sheet or of the
    # wedge around a junction edge, and only then look farther away (which
    # may reach past another sheet)
    samples, n = _face_samples(V, F)
    sides = _patch_majority(V, F, np.stack([_vote(lookup, samples, n, h, -1.0), _vote(lookup, samples, n, h, 1.0)], 1))
    for distances in ((), (1.6,), (2.5,), (4.0,)):
        for k, sign in enumerate((-1.0, 1.0)):
            sides[:, k] = _vote(lookup, samples, n, h, sign, distances, sides[:, k])
        for _ in range(3):
            sides = _fill_from_neighbours(F, sides)
            if not (sides == 0).any():
                break
            sides = _fill_around_junctions(V, F, sides)
    behind, front = sides.T
    bsamples, bn = _face_samples(BV, BF)
    ext = _vote(lookup, bsamples, bn, h, -1.0, (0.8, 1.6, 2.5, 4.0))
    ext = _fill_from_neighbours(BF, ext[:, None])[:, 0]
    for name, lab in (("fracture", np.minimum(behind, front)), ("exterior", ext)):
        if (lab == 0).any():
            f = int(np.flatnonzero(lab == 0)[0])
            which = (f"which pieces lie on the two sides of fracture triangle {f + 1}" if name == "fracture" else
                     f"which piece the object's surface triangle {f + 1} belongs to")
            raise InputError(f"{what}: cannot tell {which} (counted from 1; {int((lab == 0).sum())} such "
                             f"triangles): expected the object thicker than {2 * h:.3g} there and the cut inside it")
    same = behind == front
    if strict and same.any():
        f = int(np.flatnonzero(same)[0])
        raise InputError(f"{what}: fracture triangle {f + 1} (counted from 1) has the same piece on both sides "
                         f"({int(same.sum())} such triangles): the cut does not split the object there; expected a "
                         "cut that reaches the object's surface all round")
    # voxel regions no triangle reads (pockets cut off by walls) are not components
    used, inverse = np.unique(np.concatenate([behind, front, ext]), return_inverse=True)
    m = len(F)
    return np.stack([inverse[:m], inverse[m:2 * m]], 1), inverse[2 * m:], len(used)


def join_slivers(BV: np.ndarray, BF: np.ndarray, V: np.ndarray, F: np.ndarray, sides: np.ndarray,
                 exterior_component: np.ndarray, n: int):
    """Join pieces that hold no exterior triangle but touch B to their neighbour across the cut.

    A cut that leaves B and comes back close by (a curved sheet grazing an
    inner corner) cuts off a sliver whose patch of B is smaller than the
    labelling grid: no B triangle is labelled with it. Such a piece is
    joined to the piece on the other side of most of its fracture area,
    and the fracture triangles that then have one piece on both sides are
    dropped. A piece whose fracture triangles do not touch B is enclosed
    by the cut and stays (the caller refuses it).

    Returns ``F, sides, exterior_component, n, kept`` (``kept``: which
    triangles of ``F`` remain) and the number of pieces joined.
    """
    lonely = [c for c in range(n) if not (exterior_component == c).any()]
    if not lonely:
        return F, sides, exterior_component, n, np.ones(len(F), bool), 0
    on_b = Exterior(BV, BF).distance(V) <= tol.on_surface * diagonal(BV)
    area = face_frames(V, F)[0]
    sides = sides.copy()
    joined = 0
    for c in lonely:
        mine = (sides == c).any(axis=1)
        if not on_b[F[mine]].any():
            continue
        other = np.where(sides[mine, 0] == c, sides[mine, 1], sides[mine, 0])
        k = int(np.argmax(np.bincount(other, weights=area[mine], minlength=n)))
        sides[sides == c] = k
        joined += 1
    kept = sides[:, 0] != sides[:, 1]
    sides, exterior_component, n = _renumbered(sides[kept], exterior_component, n)
    return F[kept], sides, exterior_component, n, kept, joined


def _renumbered(sides: np.ndarray, exterior_component: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, int]:
    """The pieces that some triangle still names, numbered from 0 in their order; and how many."""
    used = np.unique(np.r_[exterior_component, sides.ravel()])
    renumber = np.full(n, -1, np.int64)
    renumber[used] = np.arange(len(used))
    return renumber[sides], renumber[exterior_component], len(used)


def join_uncut(BF: np.ndarray, sides: np.ndarray, exterior_component: np.ndarray, n: int):
    """Join pieces that no fracture triangle bounds to the piece beside them on B.

    Where the cut's rim comes within a voxel of the object's surface, the
    band around the cut that the labelling grid leaves out can seal off a
    region that no crack separates from the rest (random cut case 99: a
    ninth of an L-shape's surface, beside the cut). On B it meets its neighbours with
    no crack between: it joins the one it shares most of B's edges with. A
    piece alone on a shell of B (an object of several parts) has no such
    neighbour and stays.

    Returns ``sides, exterior_component, n`` renumbered and the number of pieces joined.
    """
    bounded = np.zeros(n, bool)
    bounded[sides.ravel()] = True
    if bounded.all():
        return sides, exterior_component, n, 0
    TT = np.asarray(igl.triangle_triangle_adjacency(np.ascontiguousarray(BF, np.int64))[0])
    ext = exterior_component.copy()
    joined = 0
    for _ in range(n):  # a region beside uncut ones only joins once one of them has
        moved = 0
        for c in np.flatnonzero(~bounded):
            mine = ext == c
            across = TT[mine]
            across = across[across >= 0]  # B's triangles beside the region's (-1: none, an open edge)
            beside = ext[across][bounded[ext[across]]]
            if len(beside):
                ext[mine] = int(np.argmax(np.bincount(beside, minlength=n)))
                moved += 1
        joined += moved
        if not moved:
            break
    return (*_renumbered(sides, ext, n), joined)

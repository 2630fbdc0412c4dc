"""The coarse fracture animation in material space (Section 4.1).

One shared, non-manifold fracture surface stores every fracture triangle once
with the ids of the components on its two sides, so an update to a vertex is
seen by every component (this replaces the paper's linked lists of
corresponding vertices). Around it: the exterior surface B, the components,
the special (boundary and non-manifold) edges and vertices, the coarse
animation and the fracture time of every fracture location.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from fracture.coarse.animation import CoarseAnimation
from fracture.mesh.topology import directed_edges, unique_edges


@dataclass
class SpecialEdges:
    """Edges of a fracture surface with their number of incident triangles.

    Attributes
    ----------
    edges : (e, 2) int
        Unique undirected edges (sorted vertex pairs).
    count : (e,) int
        Number of incident triangles.
    boundary : (e,) bool
        One incident triangle: the edge lies on the exterior B.
    nonmanifold : (e,) bool
        More than two incident triangles: a junction of cuts.
    boundary_vertices, nonmanifold_vertices : (n,) bool
        Vertices on such edges.
    """

    edges: np.ndarray
    count: np.ndarray
    boundary: np.ndarray
    nonmanifold: np.ndarray
    boundary_vertices: np.ndarray
    nonmanifold_vertices: np.ndarray


def special_edges(F: np.ndarray, n_vertices: int) -> SpecialEdges:
    """Label the boundary and non-manifold edges and vertices of a triangle mesh."""
    edges, count = unique_edges(F)
    boundary = count == 1
    nonmanifold = count > 2
    bv = np.zeros(n_vertices, bool)
    bv[edges[boundary].ravel()] = True
    nv = np.zeros(n_vertices, bool)
    nv[edges[nonmanifold].ravel()] = True
    return SpecialEdges(edges, count, boundary, nonmanifold, bv, nv)


def flood_fill_patches(F: np.ndarray, cut_edges: np.ndarray) -> np.ndarray:
    """Label the patches of a surface separated by ``cut_edges`` (Figure 3c).

    Two triangles are in one patch when they share an edge that is not cut.

    Parameters
    ----------
    F : (m, 3) int
    cut_edges : (k, 2) int
        Undirected edges that separate patches.

    Returns
    -------
    (m,) int
        Patch id of every triangle, numbered by first triangle.
    """
    m = len(F)
    E = np.sort(directed_edges(F), axis=1)
    tri = np.repeat(np.arange(m), 3)
    key = E[:, 0].astype(np.int64) * (E.max() + 1) + E[:, 1]
    if len(cut_edges):
        cut = np.sort(np.asarray(cut_edges), axis=1)
        cut_key = cut[:, 0].astype(np.int64) * (E.max() + 1) + cut[:, 1]
        keep = ~np.isin(key, cut_key)
    else:
        keep = np.ones(len(key), bool)
    order = np.argsort(key[keep], kind="stable")
    k, t = key[keep][order], tri[keep][order]
    same = k[1:] == k[:-1]
    a, b = t[:-1][same], t[1:][same]
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(m, m))
    _, label = connected_components(graph, directed=False)
    _, first = np.unique(label, return_index=True)
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(np.argsort(first))] = np.arange(len(first))  # number by first triangle
    return rank[label]


def exterior_patches(V: np.ndarray, F: np.ndarray, BV: np.ndarray, BF: np.ndarray) -> np.ndarray:
    """Patches of the exterior B cut out by the fracture surface's boundary.

    The boundary vertices of the fracture surface ``(V, F)`` are vertices of
    B; its boundary edges are the cut edges of :func:`flood_fill_patches`.

    Returns
    -------
    (len(BF),) int
        Patch id of every exterior triangle.
    """
    from scipy.spatial import cKDTree

    sp = special_edges(F, len(V))
    _, on_b = cKDTree(BV).query(V[sp.edges[sp.boundary].ravel()])
    return flood_fill_patches(BF, on_b.reshape(-1, 2))


def separation_times(V: np.ndarray, F: np.ndarray, sides: np.ndarray, animation: CoarseAnimation,
                     distance: float, opens: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """First frame at which the two sides of each fracture location separate.

    A vertex separates at frame ``t`` when its positions under the
    deformations of two components meeting there differ by more than
    ``distance``; it stays "never" (``animation.n_frames``) otherwise.
    Triangles with ``opens[f] == False`` (virtual fracture) never separate
    and do not contribute.

    Returns
    -------
    face_time : (m,) int
        Earliest separation among a triangle's corners across its two sides.
    vertex_time : (n,) int
        Earliest separation of a vertex across any pair of components that
        meet at it through a triangle.
    """
    T = animation.n_frames
    never = T
    opens = np.ones(len(F), bool) if opens is None else np.asarray(opens, bool)
    # positions of every fracture vertex under every component touching it
    traj = {}
    for c in np.unique(sides):
        verts = np.unique(F[(sides == c).any(axis=1)])
        traj[c] = (verts, animation.trajectories(int(c), V[verts]))

    def position(c, v):  # (T, k, 3) for vertices v moving with component c
        verts, X = traj[c]
        return X[:, np.searchsorted(verts, v)]

    face_time = np.full(len(F), never, np.int64)
    vertex_time = np.full(len(V), never, np.int64)
    pairs = np.unique(np.sort(sides[opens], axis=1), axis=0)
    for a, b in pairs:
        sel = opens & (np.sort(sides, axis=1) == (a, b)).all(axis=1)
        v = np.unique(F[sel])
        gap = np.linalg.norm(position(a, v) - position(b, v), axis=2)  # (T, k)
        apart = gap > distance
        first = np.where(apart.any(axis=0), apart.argmax(axis=0), never)
        np.minimum.at(vertex_time, v, first)
        per_corner = first[np.searchsorted(v, F[sel])]
        face_time[sel] = per_corner.min(axis=1)
    return face_time, vertex_time


@dataclass(frozen=True)
class SourceFrames:
    """How the input numbered its frames and measured space, so that the outputs it goes back to keep them
    (a USD file's time codes, frame rate and unit; the numbers in a sequence's file names).

    Attributes
    ----------
    first_frame : float
        The number (time code) of the input's first frame.
    frame_step : float
        Between the numbers of consecutive frames (2: the input kept every other frame).
    fps : float or None
        Frames (time codes) per second the input records; None: it does not say.
    meters_per_unit : float or None
        The input's unit of length in metres; None: it does not say.
    """

    first_frame: float = 1.0
    frame_step: float = 1.0
    fps: float | None = None
    meters_per_unit: float | None = None

    def file_numbers(self, n_frames: int) -> list[int]:
        """The numbers of ``n_frames`` frames' files: the input's (a shot from 1001 gives frame_1001 on),
        or 1, 2, ... where the input's are not whole non-negative numbers (USD time codes 0.5 apart)."""
        numbers = self.first_frame + self.frame_step * np.arange(n_frames)
        if len(numbers) and (numbers.min() >= 0) and np.all(numbers == np.round(numbers)):
            return [int(k) for k in numbers]
        return list(range(1, n_frames + 1))


@dataclass
class CoarseFracture:
    """Everything the refinement and the animation consume, in material space.

    Attributes
    ----------
    exterior_V, exterior_F : (nb, 3) float, (mb, 3) int
        The exterior surface B (closed, outward).
    exterior_component : (mb,) int
        Component of every exterior triangle.
    V, F : (n, 3) float, (m, 3) int
        The shared coarse fracture surface; its boundary vertices lie on B.
    sides : (m, 2) int
        Components behind and in front of each triangle (normal points into ``sides[:, 1]``).
    names : list of str
        Component names (the piece names of an import).
    animation : CoarseAnimation
    face_fracture_time, vertex_fracture_time : (m,) int, (n,) int
        First frame of separation; ``animation.n_frames`` means never.
    virtual : (m,) bool
        Virtual fracture (an extended incomplete cut): never opens.
    fit_residual : (C, T) float
        Largest error of the fitted deformation per component and frame
        (zero for built-in animations).
    notes : list of str
        What was repaired or assumed on import.
    up_axis : str
        The axis pointing up in the input ("x", "y" or "z"), for the outputs' up axis.
    source : SourceFrames
        The input's frame numbers, frame rate and unit, for the outputs.
    """

    exterior_V: np.ndarray
    exterior_F: np.ndarray
    exterior_component: np.ndarray
    V: np.ndarray
    F: np.ndarray
    sides: np.ndarray
    names: list[str]
    animation: CoarseAnimation
    face_fracture_time: np.ndarray
    vertex_fracture_time: np.ndarray
    virtual: np.ndarray
    fit_residual: np.ndarray
    notes: list[str] = field(default_factory=list)
    up_axis: str = "z"
    source: SourceFrames = field(default_factory=SourceFrames)

    @property
    def n_components(self) -> int:
        return len(self.names)

    @property
    def n_frames(self) -> int:
        return self.animation.n_frames

    def special(self) -> SpecialEdges:
        return special_edges(self.F, len(self.V))

    def exterior_patches(self) -> np.ndarray:
        """Patch id of every exterior triangle (see :func:`exterior_patches`)."""
        return exterior_patches(self.V, self.F, self.exterior_V, self.exterior_F)


def make_coarse(BV: np.ndarray, BF: np.ndarray, exterior_component: np.ndarray, V: np.ndarray, F: np.ndarray,
                sides: np.ndarray, names: list[str], animation: CoarseAnimation, separation: float,
                virtual: np.ndarray | None = None, fit_residual: np.ndarray | None = None,
                notes: list[str] | None = None) -> CoarseFracture:
    """Assemble a :class:`CoarseFracture`, deriving the fracture times from the animation.

    ``separation`` is the distance (relative to B's box diagonal) at which
    the two sides of a fracture location count as separated.
    """
    diag = float(np.linalg.norm(np.ptp(BV, axis=0)))
    virtual = np.zeros(len(F), bool) if virtual is None else np.asarray(virtual, bool)
    face_time, vertex_time = separation_times(V, F, sides, animation, separation * diag, ~virtual)
    if fit_residual is None:
        fit_residual = np.zeros((animation.n_components, animation.n_frames))
    return CoarseFracture(
        exterior_V=np.asarray(BV, np.float64), exterior_F=np.asarray(BF, np.int64),
        exterior_component=np.asarray(exterior_component, np.int64), V=np.asarray(V, np.float64),
        F=np.asarray(F, np.int64), sides=np.asarray(sides, np.int64), names=list(names), animation=animation,
        face_fracture_time=face_time, vertex_fracture_time=vertex_time, virtual=virtual,
        fit_residual=fit_residual, notes=list(notes or []),
    )

"""Watertight high-resolution pieces from B and the refined fracture surface (Section 5).

After :func:`fracture.imprint.imprint_boundary`, B's cut edges are the
refined surface S's boundary edges. B splits along them into patches; each
patch belongs to the component on its side of the S triangle at its cut
edges. A piece is its component's patches plus every S triangle with the
component on one side, turned so that the normal points out of it: one
closed, 2-manifold, outward mesh per component.

All pieces index one vertex array: S's vertices (shared by the pieces that
meet there) followed by B's vertices off the cut.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import igl
import numpy as np

from fracture.coarse import flood_fill_patches
from fracture.imprint import Imprint
from fracture.refine.collide import self_intersections
from fracture.refine.mesh import RefineMesh
from fracture.topology import directed_edge_face, directed_edges, signed_volume


@dataclass
class Pieces:
    """One closed mesh per component over a shared vertex array.

    Attributes
    ----------
    V : (n, 3) float
        Material-space positions: the refined fracture surface's vertices
        (the first ``n_fracture``) and then B's vertices that are not on it.
    n_fracture : int
    faces : list of (m_c, 3) int
        Triangles of each piece (component order), indexing ``V``.
    exterior : list of (m_c,) bool
        Which triangles of a piece come from B.
    patch_agreement : float
        Smallest share, over B's patches, of the cut-edge votes that agree
        with the patch's component (1 when every cut edge agrees).
    """

    V: np.ndarray
    n_fracture: int
    faces: list
    exterior: list
    patch_agreement: float

    @property
    def n_pieces(self) -> int:
        return len(self.faces)

    @cached_property
    def parts(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Per piece: vertex ids (into ``V``, sorted), local vertices and local triangles."""
        out = []
        for F in self.faces:
            ids, local = np.unique(F, return_inverse=True)
            out.append((ids, self.V[ids], local.reshape(-1, 3)))
        return out

    def piece(self, c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vertex ids (into ``V``), local vertices and local triangles of piece ``c``."""
        return self.parts[c]


def label_patches(im: Imprint, mesh: RefineMesh, n_components: int, fallback) -> tuple[np.ndarray, float]:
    """Component of each of B's triangles, by patch.

    At a cut edge, a B triangle on the front of the S triangle there (the
    side its normal points to) belongs to that triangle's ``sides[:, 1]``,
    one behind it to ``sides[:, 0]``. Each patch takes the component most of
    its cut edges vote for, weighted by how clearly the B triangle lies on
    one side. Patches with no cut edge take ``fallback(face_ids)``, the
    components of their triangles by another rule (majority).
    """
    patch = flood_fill_patches(im.F, im.cut_edges)
    n_patch = int(patch.max()) + 1 if len(patch) else 0
    E = im.cut_edges
    T = mesh.F[im.cut_faces]
    n = np.cross(mesh.V[T[:, 1]] - mesh.V[T[:, 0]], mesh.V[T[:, 2]] - mesh.V[T[:, 0]])
    mid = 0.5 * (im.V[E[:, 0]] + im.V[E[:, 1]])
    votes = np.zeros((n_patch, n_components))
    for directed in (E, E[:, ::-1]):
        f = directed_edge_face(im.F, directed)
        w = im.V[im.F[f]].mean(axis=1) - mid
        side = np.einsum("ij,ij->i", w, n)
        weight = np.abs(side) / np.maximum(np.linalg.norm(w, axis=1) * np.linalg.norm(n, axis=1), 1e-300)
        comp = np.where(side > 0, mesh.sides[im.cut_faces, 1], mesh.sides[im.cut_faces, 0])
        np.add.at(votes, (patch[f], comp), weight)
    label = votes.argmax(axis=1)
    total = votes.sum(axis=1)
    voted = total > 0
    agreement = float((votes.max(axis=1)[voted] / total[voted]).min()) if voted.any() else 1.0
    for p in np.flatnonzero(~voted):
        faces = np.flatnonzero(patch == p)
        label[p] = np.bincount(fallback(faces), minlength=n_components).argmax()
    return label[patch], agreement


def build_pieces(im: Imprint, mesh: RefineMesh, n_components: int, fallback) -> Pieces:
    """Assemble the closed pieces from imprinted B ``im`` and the refined surface ``mesh``.

    ``fallback(face_ids)`` labels B triangles of patches that touch no cut
    (see :func:`label_patches`).
    """
    component, agreement = label_patches(im, mesh, n_components, fallback)
    n_s = len(mesh.V)
    off = im.to_fracture < 0
    to_u = im.to_fracture.copy()
    to_u[off] = n_s + np.arange(int(off.sum()))
    V = np.concatenate([mesh.V, im.V[off]])
    faces, exterior = [], []
    for c in range(n_components):
        fb = to_u[im.F[component == c]]
        front = mesh.F[mesh.sides[:, 0] == c]  # normal points away from c: outward already
        back = mesh.F[mesh.sides[:, 1] == c][:, ::-1]
        F = np.concatenate([fb, front, back])
        ext = np.r_[np.ones(len(fb), bool), np.zeros(len(front) + len(back), bool)]
        keep = ~_cancelling(F, len(V))
        faces.append(F[keep])
        exterior.append(ext[keep])
    return Pieces(V=V, n_fracture=n_s, faces=faces, exterior=exterior, patch_agreement=agreement)


def _cancelling(F: np.ndarray, n: int) -> np.ndarray:
    """Triangles that come in pairs on the same corners with opposite orientations (a fin of no volume).

    A fracture triangle lying on B (its corners all on the cut) meets B's
    triangle there face to face; the two bound nothing and both go.
    """
    S = np.sort(F, axis=1)
    key = (S[:, 0] * n + S[:, 1]) * n + S[:, 2]
    _, inv, count = np.unique(key, return_inverse=True, return_counts=True)
    twin = np.flatnonzero(count[inv] == 2)
    out = np.zeros(len(F), bool)
    if len(twin):
        # even permutations of the sorted corners have the same orientation
        rot = F[twin] == S[twin, :1]
        k = rot.argmax(axis=1)
        second = F[twin, (k + 1) % 3]
        parity = second == S[twin, 1]
        order = np.argsort(inv[twin], kind="stable")
        a, b = order[0::2], order[1::2]
        opposite = parity[a] != parity[b]
        out[twin[a[opposite]]] = out[twin[b[opposite]]] = True
    return out


def mesh_checks(V: np.ndarray, F: np.ndarray, intersections: bool = True) -> dict:
    """Closedness, manifoldness, orientation, volume and self-intersections of one mesh.

    ``closed_oriented``: every directed edge appears once and its reverse
    once (closed, edge-manifold and consistently oriented together).
    """
    D = directed_edges(F)
    n = len(V)
    key = D[:, 0] * n + D[:, 1]
    rev = D[:, 1] * n + D[:, 0]
    uniq, count = np.unique(key, return_counts=True)
    pos = np.minimum(np.searchsorted(uniq, rev), len(uniq) - 1)
    closed_oriented = bool((count == 1).all() and (uniq[pos] == rev).all())
    vertex_manifold = bool(np.asarray(igl.is_vertex_manifold(np.ascontiguousarray(F, np.int64))).all())
    out = {"closed_oriented": closed_oriented, "vertex_manifold": vertex_manifold,
           "volume": signed_volume(V, F), "triangles": int(len(F)), "vertices": int(len(V))}
    if intersections:
        out["self_intersections"] = int(self_intersections(V, F))
    return out


def overlap_and_gap(pieces: Pieces, BV: np.ndarray, BF: np.ndarray, samples: int, rng) -> tuple[float, float]:
    """Shares of sample points inside B that lie in more than one piece, and in none.

    Points are drawn uniformly in B's box; insideness is the winding number.
    """
    lo, hi = BV.min(axis=0), BV.max(axis=0)
    P = lo + (hi - lo) * rng.random((samples, 3))
    inside_b = igl.fast_winding_number(np.ascontiguousarray(BV), np.ascontiguousarray(BF, np.int64), P) > 0.5
    P = P[inside_b]
    count = np.zeros(len(P), np.int64)
    for c in range(pieces.n_pieces):
        _, V, F = pieces.piece(c)
        count += igl.fast_winding_number(V, np.ascontiguousarray(F, np.int64), P) > 0.5
    n = max(len(P), 1)
    return float((count > 1).sum() / n), float((count == 0).sum() / n)

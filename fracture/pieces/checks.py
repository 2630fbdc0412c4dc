"""What a run checks of its pieces before it succeeds (Section 5): each piece closed, oriented,
manifold, free of self-intersections and of the volume its winding number claims; together they hold
the object's volume without overlap; their exterior stays on B, and copies of one vertex stay
together before its fracture time."""

from __future__ import annotations

import igl
import numpy as np

from fracture.errors import ResultError
from fracture.mesh.topology import diagonal, signed_volume
from fracture.pieces.assembly import Pieces, mesh_checks, overlap_and_gap
from fracture.pieces.transfer import Transfer
from fracture.tolerances import tol


def piece_checks(pieces: Pieces, BV: np.ndarray, BF: np.ndarray, samples: int, rng: np.random.Generator) -> dict:
    """Per-piece mesh checks, the volume balance and the overlap sampling at ``samples`` random points
    (material space): what :func:`verify_pieces` judges and the manifest records."""
    per_piece = []
    total = 0.0
    for c, (_, V, F) in enumerate(pieces.parts):
        ch = mesh_checks(V, F, intersections=False)
        if pieces.crossings is not None:  # counted (exactly) while resolving
            ch.update(self_intersections=pieces.crossings[c], crossings_resolved=pieces.resolved[c])
        total += ch["volume"]
        per_piece.append(ch)
    vb = signed_volume(BV, BF)
    out = {"pieces": per_piece, "volume_B": vb, "volume_pieces": total,
           "volume_relative_error": abs(total - vb) / abs(vb), "patch_agreement": pieces.patch_agreement,
           "jitter_seed": pieces.jitter_seed}
    overlap, gap, share, n = overlap_and_gap(pieces, BV, BF, samples, rng)
    out.update(overlap_share=overlap, uncovered_share=gap, samples_inside=n)
    for ch, p in zip(per_piece, share):
        ch["volume_sampled"] = float(p * vb)
    return out


# What a verified set of pieces may miss: of B's volume in all (slivers of S
# grazing B are kept by one piece), and of the sample points in two pieces.
VOLUME_BALANCE = 0.01
OVERLAP_SHARE = 0.005


def verify_pieces(checks: dict, names: list[str]) -> None:
    """Refuse pieces that are not what a run promises (a :class:`ResultError` naming the piece).

    Each piece must be closed and consistently oriented, vertex-manifold,
    free of self-intersections (where they were counted, exactly), with a
    positive volume that agrees with the share of sample points its winding
    number claims (within five standard errors of the sampling); together
    the pieces must hold B's volume and not overlap.
    """
    vb = checks["volume_B"]
    n = checks.get("samples_inside", 0)
    for c, p in enumerate(checks["pieces"]):
        what = f"animate: piece {c} ({names[c]})"
        if not p["closed_oriented"]:
            raise ResultError(f"{what} is not closed with consistently oriented faces, so it would not be solid")
        if p.get("self_intersections", 0):
            raise ResultError(f"{what} crosses itself ({p['self_intersections']} triangle pairs meet) and the "
                              "crossings could not be resolved")
        if not p["vertex_manifold"]:
            raise ResultError(f"{what} is pinched at a vertex (not a 2-manifold)")
        if p["volume"] <= 0:
            raise ResultError(f"{what} has volume {p['volume']:.3g}; it is inside out or empty")
        if "volume_sampled" in p and n:
            share = min(max(p["volume_sampled"] / vb, 0.0), 1.0)
            allowed = 5.0 * abs(vb) * np.sqrt(max(share * (1.0 - share), 1.0 / n) / n) + tol.volume_check * abs(vb)
            if abs(p["volume"] - p["volume_sampled"]) > allowed:
                raise ResultError(f"{what}: its volume {p['volume']:.4g} disagrees with the {p['volume_sampled']:.4g} "
                                  f"its winding number encloses at {n} sample points (it wraps some space twice)")
    if checks["volume_relative_error"] > VOLUME_BALANCE:
        raise ResultError(f"animate: the pieces hold {checks['volume_pieces']:.4g} of volume where the object has "
                          f"{vb:.4g} ({100 * checks['volume_relative_error']:.2g} % off, at most "
                          f"{100 * VOLUME_BALANCE:g} % expected)")
    if checks.get("overlap_share", 0.0) > OVERLAP_SHARE:
        raise ResultError(f"animate: {100 * checks['overlap_share']:.2g} % of the object lies in two pieces at once "
                          f"(at most {100 * OVERLAP_SHARE:g} % expected)")


def hausdorff_to_b(pieces: Pieces, transfer: Transfer, X: np.ndarray, BV: np.ndarray, BF: np.ndarray) -> float:
    """Hausdorff distance (vertices to surface, both ways) between the pieces' B triangles at ``X`` and B, over B's diagonal."""
    EF = np.concatenate([F[pieces.exterior[c]] + transfer.offsets[c] for c, (_, _, F) in enumerate(pieces.parts)])
    used = np.unique(EF)
    d1 = np.sqrt(igl.point_mesh_squared_distance(np.ascontiguousarray(X[used]), BV, BF)[0].max())
    d2 = np.sqrt(igl.point_mesh_squared_distance(np.ascontiguousarray(BV), X, EF)[0].max())
    return float(max(d1, d2) / diagonal(BV))


class EarlyGap:
    """Largest distance between two copies of one vertex at a frame before its fracture time."""

    def __init__(self, transfer: Transfer):
        order = np.argsort(transfer.vertex, kind="stable")
        twin = np.flatnonzero(transfer.vertex[order][1:] == transfer.vertex[order][:-1])
        self.a, self.b = order[twin], order[twin + 1]
        self.time = transfer.time[self.a]
        self.worst = 0.0

    def add(self, t: int, X: np.ndarray) -> None:
        early = self.time > t
        if early.any():
            d = np.linalg.norm(X[self.a[early]] - X[self.b[early]], axis=1).max()
            self.worst = max(self.worst, float(d))

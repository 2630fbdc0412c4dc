"""The ``animate`` stage: watertight high-resolution pieces and their animation (Section 5).

Outputs:

* ``pieces/piece_NNN.ply``: each piece in material space (vertex property
  ``fracture_time``, the frame from which it moves with its own piece;
  face property ``exterior``, 1 on B);
* ``frames/frame_NNNN.obj`` (frames numbered from 1, as in Blender): every
  piece as an object named like the coarse piece, ready for Blender's OBJ
  import; with ``animate.ply_frames`` also ``frames/frame_NNNN.ply`` (all
  pieces, face property ``piece``);
* ``animation/pieces.usdc`` (``animate.usd``): every piece as a USD mesh
  with its points per frame and the interior (fracture) and exterior faces
  bound to two materials (:mod:`fracture.io.usd`);
* ``animation/transfer.npz``: the sparse transfer and the per-frame maps,
  from which a viewer computes any frame with one sparse product.

The manifest gets, per piece, whether it is closed, 2-manifold and
outward-oriented, its volume and self-intersections (and how many crossing
triangle pairs the resolution of :mod:`fracture.pieces.assembly` removed); the pieces' volume
against B's; the share of sample points inside more than one piece; the
Hausdorff distance between the first frame's exterior and B; the
largest gap between copies of a vertex before its fracture time; and
``jitter_seed``, nonzero when the resolution needed jittered positions.
"""

from __future__ import annotations

import copy

import igl
import numpy as np

from fracture.errors import ResultError
from fracture.pieces.imprint import imprint_boundary
from fracture.io.obj import ObjFrames
from fracture.pieces.assembly import build_pieces, mesh_checks, overlap_and_gap
from fracture.io.ply import write_ply
from fracture.pipeline.context import RunContext
from fracture.mesh.topology import diagonal, signed_volume
from fracture.pieces.transfer import Transfer, build_transfer, frame_points
from fracture.io.usd import write_pieces_usd


def animate_stage(ctx: RunContext) -> None:
    cf = ctx.products.coarse
    BV, BF = ctx.products.exterior
    opts = ctx.cfg["animate"]
    mesh = copy.deepcopy(ctx.products.refined)
    with ctx.bar(cf.n_frames + 3, "animate") as bar:
        im = imprint_boundary(BV, BF, mesh, where="animate")
        bar.update()

        def fallback(faces):  # patches without a cut: the coarse exterior's label
            centroids = im.V[im.F[faces]].mean(axis=1)
            _, f, _ = igl.point_mesh_squared_distance(centroids, cf.exterior_V, cf.exterior_F)
            return cf.exterior_component[f]

        pieces = build_pieces(im, mesh, cf.n_components, fallback)
        transfer = build_transfer(cf, pieces, mesh.tree_matrix())
        bar.update()
        checks = _check(ctx, pieces, BV, BF, opts)
        verify_pieces(checks, cf.names)
        bar.update()

        local = pieces.parts
        for c, (ids, V, F) in enumerate(local):
            rows = slice(transfer.offsets[c], transfer.offsets[c + 1])
            write_ply(ctx.path(f"pieces/piece_{c:03d}.ply"), V, F,
                      vertex_data={"fracture_time": transfer.time[rows].astype(np.float32)},
                      face_data={"exterior": pieces.exterior[c].astype(np.uint8)})
        _save_transfer(ctx, transfer)
        writer = ObjFrames(cf.names, [F for _, _, F in local], [len(ids) for ids, _, _ in local],
                           exterior=pieces.exterior)
        if opts["obj_frames"]:
            writer.write_materials(ctx.path(f"frames/{writer.materials}"))
        if opts["ply_frames"]:  # rows of piece c start at transfer.offsets[c]
            all_F = np.concatenate([F + transfer.offsets[c] for c, (_, _, F) in enumerate(local)])
            piece_of = np.repeat(np.arange(pieces.n_pieces, dtype=np.int32), [len(F) for _, _, F in local])
        gap = EarlyGap(transfer)
        for t in range(transfer.n_frames):
            X = transfer.positions(t)
            if t == 0:
                checks["hausdorff_first_frame_relative"] = _hausdorff_to_b(pieces, transfer, X, BV, BF)
            gap.add(t, X)
            if opts["obj_frames"]:
                writer.write(ctx.path(f"frames/frame_{t + 1:04d}.obj"),
                             [transfer.piece(X, c) for c in range(pieces.n_pieces)], header=f"frame {t + 1}")
            if opts["ply_frames"]:
                write_ply(ctx.path(f"frames/frame_{t + 1:04d}.ply"), X, all_F, face_data={"piece": piece_of})
            bar.update()
        checks["early_gap_max"] = gap.worst
        if opts["usd"]:
            write_pieces_usd(ctx.path("animation/pieces.usdc"), cf.names,
                             [F for _, _, F in local], pieces.exterior, frame_points(transfer), fps=opts["fps"],
                             up_axis="Y" if cf.up_axis == "y" else "Z")

    ctx.products.pieces = pieces
    ctx.products.transfer = transfer
    ctx.counts.update(pieces=pieces.n_pieces, piece_triangles=int(sum(len(f) for f in pieces.faces)),
                      frames_written=transfer.n_frames if opts["obj_frames"] else 0)
    ctx.stats["animate"] = checks


def _check(ctx: RunContext, pieces, BV, BF, opts) -> dict:
    """Per-piece mesh checks, the volume balance and the overlap sampling (material space)."""
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
    overlap, gap, share, n = overlap_and_gap(pieces, BV, BF, opts["check_samples"],
                                             np.random.default_rng(ctx.cfg["seed"]))
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
            allowed = 5.0 * abs(vb) * np.sqrt(max(share * (1.0 - share), 1.0 / n) / n) + 1e-3 * abs(vb)
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


def _hausdorff_to_b(pieces, transfer: Transfer, X: np.ndarray, BV, BF) -> float:
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


def _save_transfer(ctx: RunContext, tr: Transfer) -> None:
    ctx.save_npz("animation/transfer.npz", {
        "own_data": tr.own.data, "own_indices": tr.own.indices.astype(np.int64),
        "own_indptr": tr.own.indptr.astype(np.int64), "own_shape": np.array(tr.own.shape, np.int64),
        "shared_data": tr.shared.data, "shared_indices": tr.shared.indices.astype(np.int64),
        "shared_indptr": tr.shared.indptr.astype(np.int64), "shared_shape": np.array(tr.shared.shape, np.int64),
        "shared_rows": tr.shared_rows, "shared_time": tr.shared_time, "maps": tr.maps,
        "offsets": tr.offsets, "time": tr.time, "vertex": tr.vertex, "material": tr.material})

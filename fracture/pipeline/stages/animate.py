"""The ``animate`` stage: watertight high-resolution pieces and their animation (Section 5).

Outputs:

* ``pieces/piece_NNN.ply``: each piece in material space (vertex property
  ``fracture_time``, the frame from which it moves with its own piece;
  face property ``exterior``, 1 on B);
* ``frames/frame_NNNN.obj`` (frames numbered as the input's: a sequence's
  file numbers, a USD file's time codes; from 1 where those are not whole): every
  piece as an object named like the coarse piece, ready for Blender's OBJ
  import; with ``animate.ply_frames`` also ``frames/frame_NNNN.ply`` (all
  pieces, face property ``piece``);
* ``animation/pieces.usdc`` (``animate.usd``): every piece as a USD mesh
  under an Xform whose transform moves it (its points per frame only where
  it deforms), the interior (fracture) and exterior faces bound to two
  materials (:mod:`fracture.io.usd`);
* ``animation/transfer.npz``: the sparse transfer and the per-frame maps
  (once per component and frame where it moves rigidly, compressed:
  :func:`~fracture.pieces.transfer.transfer_arrays`), from which a viewer
  computes any frame with one sparse product.

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
from dataclasses import asdict

import igl
import numpy as np

from fracture.errors import JoinError
from fracture.io import layout
from fracture.mesh.exterior import Exterior
from fracture.mesh.topology import closed_oriented
from fracture.pieces.holes import close_holes, holes_at
from fracture.pieces.imprint import imprint_boundary, median_edge
from fracture.io.obj import ObjFrames
from fracture.pieces.assembly import build_pieces
from fracture.pieces.checks import EarlyGap, hausdorff_to_b, piece_checks, verify_pieces
from fracture.io.ply import write_ply
from fracture.pipeline.context import RunContext
from fracture.pieces.transfer import Transfer, build_transfer, frame_points, rest_points, transfer_arrays
from fracture.io.usd import usd_timing, write_pieces_usd


def animate_stage(ctx: RunContext) -> None:
    cf = ctx.products.coarse
    BV, BF = ctx.products.exterior
    opts = ctx.config.animate
    with ctx.bar(cf.n_frames + 3, "animate") as bar:
        mesh, im, pieces, holes = _pieces(ctx, BV, BF)
        if holes:
            ctx.notes.append(f"animate: {holes} small {'holes' if holes > 1 else 'hole'} of the refined surface where it "
                             "touched the object's surface (rims that cut it inconsistently) closed, so that the "
                             "pieces close")
        if im.merged_off_b:
            ctx.notes.append(f"animate: {im.merged_off_b} boundary {'vertices' if im.merged_off_b > 1 else 'vertex'} of the "
                             "refined surface that collisions had kept off the object's surface merged into a "
                             "neighbour, so that the cracks could be cut into it")
        if im.rim_collapsed:
            ctx.notes.append(f"animate: {im.rim_collapsed} short {'edges' if im.rim_collapsed > 1 else 'edge'} of the "
                             "refined surface's boundary collapsed where its cracks could not be cut into the object's "
                             "surface as they were (a boundary that doubles back on itself there)")
        if im.joined_b:
            ctx.notes.append(f"animate: the cracks could not be cut into the object's surface as it was; its edges "
                             f"shorter than a tenth of its typical edge (slivers and bumps of the import's contour) were "
                             f"collapsed ({im.joined_b} vertices joined), and then they could")
        bar.update()
        transfer = build_transfer(cf, pieces, mesh.tree_matrix())
        bar.update()
        checks = piece_checks(pieces, BV, BF, opts.check_samples, np.random.default_rng(ctx.config.seed))
        verify_pieces(checks, cf.names)
        bar.update()

        local = pieces.parts
        for c, (ids, V, F) in enumerate(local):
            rows = slice(transfer.offsets[c], transfer.offsets[c + 1])
            write_ply(ctx.path(layout.piece(c)), V, F,
                      vertex_data={"fracture_time": transfer.time[rows].astype(np.float32)},
                      face_data={"exterior": pieces.exterior[c].astype(np.uint8)})
        _save_transfer(ctx, transfer)
        writer = ObjFrames(cf.names, [F for _, _, F in local], [len(ids) for ids, _, _ in local],
                           exterior=pieces.exterior)
        if opts.obj_frames:
            writer.write_materials(ctx.path(f"frames/{writer.materials}"))
        if opts.ply_frames:  # rows of piece c start at transfer.offsets[c]
            all_F = np.concatenate([F + transfer.offsets[c] for c, (_, _, F) in enumerate(local)])
            piece_of = np.repeat(np.arange(pieces.n_pieces, dtype=np.int32), [len(F) for _, _, F in local])
        gap = EarlyGap(transfer)
        numbers = cf.source.file_numbers(transfer.n_frames)
        for t in range(transfer.n_frames):
            X = transfer.positions(t)
            if t == 0:
                checks["hausdorff_first_frame_relative"] = hausdorff_to_b(pieces, transfer, X, BV, BF)
            gap.add(t, X)
            if opts.obj_frames:
                writer.write(ctx.path(layout.frame(numbers[t], ".obj")),
                             [transfer.piece(X, c) for c in range(pieces.n_pieces)], header=f"frame {numbers[t]}")
            if opts.ply_frames:
                write_ply(ctx.path(layout.frame(numbers[t])), X, all_F, face_data={"piece": piece_of})
            bar.update()
        checks["early_gap_max"] = gap.worst
        if opts.usd:
            write_pieces_usd(ctx.path(layout.USD), cf.names,
                             [F for _, _, F in local], pieces.exterior, frame_points(transfer),
                             rest=rest_points(transfer), size=transfer.size,
                             up_axis="Y" if cf.up_axis == "y" else "Z", **usd_timing(opts.fps, **asdict(cf.source)))

    ctx.products.pieces = pieces
    ctx.products.transfer = transfer
    ctx.counts.update(pieces=pieces.n_pieces, piece_triangles=int(sum(len(f) for f in pieces.faces)),
                      frames_written=transfer.n_frames if opts.obj_frames else 0)
    ctx.stats["animate"] = {**checks, "boundary_vertices_merged_off_b": im.merged_off_b,
                            "exterior_vertices_joined": im.joined_b,
                            "boundary_edges_collapsed": im.rim_collapsed, "small_holes_closed": holes}


def _pieces(ctx: RunContext, BV: np.ndarray, BF: np.ndarray):
    """The refined surface (a copy) imprinted on B, and the pieces: if a piece is not closed because a small
    hole of the surface cuts B inconsistently (:mod:`fracture.pieces.holes`), made again with those holes
    closed. Returns the surface, the imprint, the pieces and how many holes were closed."""
    cf = ctx.products.coarse

    def fallback(im):
        def label(faces):  # patches without a cut: the coarse exterior's label
            centroids = im.V[im.F[faces]].mean(axis=1)
            _, f, _ = igl.point_mesh_squared_distance(centroids, cf.exterior_V, cf.exterior_F)
            return cf.exterior_component[f]
        return label

    mesh = copy.deepcopy(ctx.products.refined)
    im = imprint_boundary(BV, BF, mesh, where="animate")
    pieces = build_pieces(im, mesh, cf.n_components, fallback(im))
    if all(closed_oriented(F) for F in pieces.faces) or not len(pieces.dissent):
        return mesh, im, pieces, 0
    B = Exterior(BV, BF)
    h = median_edge(B.V, B.F)
    again = copy.deepcopy(ctx.products.refined)
    holes = close_holes(again, holes_at(again, pieces.dissent, h), B, h)
    if not holes:
        return mesh, im, pieces, 0
    try:
        closed = imprint_boundary(BV, BF, again, where="animate")
    except JoinError:  # the first refusal stands: its pieces do not close
        return mesh, im, pieces, 0
    return again, closed, build_pieces(closed, again, cf.n_components, fallback(closed)), holes


def _save_transfer(ctx: RunContext, tr: Transfer) -> None:
    ctx.save_npz(layout.TRANSFER, transfer_arrays(tr, tr.size), compress=True)

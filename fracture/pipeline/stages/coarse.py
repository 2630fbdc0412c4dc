"""The ``coarse`` stage: the coarse fracture animation in material space (Section 4.1)."""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping

import numpy as np

from fracture.coarse.surface import CoarseFracture, make_coarse
from fracture.coarse.mesh_sequence import load_coarse_sequence
from fracture.io import layout
from fracture.io.meshes import read_mesh
from fracture.io.ply import write_ply
from fracture.pipeline.context import RunContext
from fracture.pipeline.schema import InputSection


def coarse_from_meshes(inp: InputSection | Mapping) -> CoarseFracture:
    """A still object from an exterior and a coarse fracture surface (``input.kind: meshes``).

    Incomplete cuts are extended (virtual fracture) and the components found
    by flood fill; the animation is the rest pose alone.
    """
    from fracture.coarse.components import join_slivers, join_uncut, label_components
    from fracture.errors import InputError
    from fracture.mesh.topology import orient_sheets
    from fracture.coarse.animation import exterior_points, lattice_animation
    from fracture.coarse.trim import trim_to_object
    from fracture.coarse.virtual import extend_cuts

    if isinstance(inp, Mapping):  # the section as a plain mapping; the keys it lacks take their defaults
        inp = InputSection(**inp)
    missing = [k for k in ("exterior", "fracture") if not getattr(inp, k)]
    if missing:
        raise InputError("coarse: input.kind 'meshes' needs the object's exterior and coarse fracture surface; set "
                         + " and ".join(f"input.{k}" for k in missing) + " to mesh files (OBJ, PLY, OFF or STL)")
    BV, BF, notes = read_exterior(inp.exterior)
    what = f"input.fracture ({inp.fracture})"
    V, F = read_mesh(inp.fracture, "input.fracture")
    # the pieces follow the sides of each triangle, so a sheet's triangles must agree (any one way)
    F, turned, conflict = orient_sheets(F)
    if conflict is not None:
        raise InputError(f"{what}: faces {conflict[0] + 1} and {conflict[1] + 1} "
                         "(counted from 1 in the file) lie on a one-sided sheet (a Moebius strip): its two sides "
                         "cannot be told apart; expected sheets with two sides")
    if turned:
        notes.append(f"input.fracture: {turned} faces turned to agree with their neighbours")
    V, F, outside = trim_to_object(V, F, BV, BF)
    if not len(F):
        raise InputError(f"{what}: no part of the fracture surface lies inside the object (input.exterior, "
                         f"{inp.exterior}); expected a cut through it")
    if outside:
        notes.append(f"input.fracture: trimmed to the object ({100 * outside:.1f} % of its area was outside)")
    V, F, virtual = extend_cuts(V, F, BV, BF)
    sides, ext, n = label_components(BV, BF, V, F, what=what, strict=False)
    same = sides[:, 0] == sides[:, 1]
    if same.all():
        raise InputError(f"{what}: the cut does not split the object anywhere, even extended to the object's "
                         f"surface (every one of its {len(F)} triangles has the same piece on both sides); expected "
                         "a cut that separates the object into pieces")
    if same.any():  # parts that end inside a piece and that no extension completes: left out
        F, virtual = F[~same], virtual[~same]
        notes.append(f"input.fracture: {int(same.sum())} triangles of the cut have the same piece on both sides "
                     "(a crack that ends inside a piece): left out")
        V, F, virtual = extend_cuts(V, F, BV, BF, virtual=virtual)  # what was left out may leave a crack front
        sides, ext, n = label_components(BV, BF, V, F, what=what)
    F, sides, ext, n, kept, joined = join_slivers(BV, BF, V, F, sides, ext, n)
    virtual = virtual[kept]
    if joined:
        notes.append(f"input.fracture: {joined} sliver piece{'s' if joined > 1 else ''} between the cut and the "
                     "object's surface, too thin for the labelling grid, joined to the neighbour across the cut "
                     f"({int((~kept).sum())} triangles dropped)")
    sides, ext, n, uncut = join_uncut(BF, sides, ext, n)
    if uncut:
        notes.append(f"input.fracture: {uncut} region{'s' if uncut > 1 else ''} of the object that no crack "
                     "separates from the rest (the labelling grid had cut it off) joined to the piece beside "
                     f"{'them' if uncut > 1 else 'it'}")
    enclosed = [c for c in range(n) if not (ext == c).any()]
    if enclosed:
        faces = np.flatnonzero((sides == enclosed[0]).any(axis=1) & ~virtual)
        raise InputError(f"{what}: the fracture surface encloses a piece that does not reach the object's surface "
                         f"(the piece inside faces {', '.join(str(f + 1) for f in faces[:5])}"
                         f"{' ...' if len(faces) > 5 else ''}, counted from 1); expected every piece to have part "
                         "of the exterior")
    still = lattice_animation(exterior_points(BV, BF, ext, n), lambda c, t, X: X, 1)
    if virtual.any():
        notes.append(f"virtual fracture: {int(virtual.sum())} triangles extend incomplete cuts")
    return make_coarse(BV, BF, ext, V, F, sides, [f"piece_{c:03d}" for c in range(n)], still, inp.separation,
                       virtual=virtual, notes=notes)


def read_exterior(path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The object's closed exterior, oriented outward (cavities inward), and notes on what was turned."""
    from fracture.errors import InputError
    from fracture.mesh.clean import remove_flat_triangles
    from fracture.mesh.intersect import self_intersections
    from fracture.mesh.topology import orient_outward

    BV, BF = read_mesh(path, "input.exterior", closed=True)
    BF, turned, conflict = orient_outward(BV, BF)
    if conflict is not None:
        raise InputError(f"input.exterior ({path}): faces {conflict[0] + 1} and {conflict[1] + 1} (counted from 1) "
                         "lie on a one-sided surface; expected the closed surface of a solid")
    BV, BF, flat = remove_flat_triangles(BV, BF)
    count, pairs = self_intersections(BV, BF, report=1)
    if count:  # two overlapping shells: one of them is taken for a cavity, and the solid has no volume to cut
        raise InputError(f"input.exterior ({path}): the surface crosses or touches itself ({count} pairs of faces, first faces "
                         f"{pairs[0, 0] + 1} and {pairs[0, 1] + 1}, counted from 1); expected the closed surface of one "
                         "solid (join overlapping parts into one, with a boolean union)")
    notes = [f"input.exterior: {flat} triangles without area removed (corners merged or flipped away)"] if flat else []
    if turned:
        notes.append(f"input.exterior: {turned} faces turned to face outward")
    return BV, BF, notes


def coarse_stage(ctx: RunContext) -> None:
    inp = ctx.config.input
    extra = {}
    with ctx.bar(1, f"coarse: {inp.kind}") as bar:
        if inp.kind == "mesh_sequence":
            cf, extra = load_coarse_sequence(inp.path, inp.glob, inp.lattice, inp.separation,
                                             inp.up_axis)
        elif inp.kind == "usd":
            from fracture.coarse.mesh_sequence import coarse_from_frames
            from fracture.coarse.usd_input import read_usd_frames

            usd = read_usd_frames(inp.usd)
            up = usd.up_axis if inp.up_axis == "auto" else inp.up_axis
            cf, extra = coarse_from_frames(usd.frames, inp.lattice, inp.separation, up)
            cf.source = replace(cf.source, fps=usd.fps, meters_per_unit=usd.meters_per_unit)
            if usd.hidden:
                cf.notes.insert(0, f"left out {len(usd.hidden)} invisible or guide or proxy "
                                   f"mesh{'es' if len(usd.hidden) > 1 else ''} of the USD file: "
                                   + ", ".join(usd.hidden[:5]) + (", ..." if len(usd.hidden) > 5 else ""))
        elif inp.kind == "scene":
            from fracture.coarse.scenes import build_scene

            cf = build_scene(inp.scene, ctx.config.seed, inp.frames, inp.separation)
        else:
            cf = coarse_from_meshes(inp)
            cf.up_axis = "z" if inp.up_axis == "auto" else inp.up_axis  # a still object: nothing falls
        bar.update()
    if inp.kind in ("mesh_sequence", "usd") and inp.exterior is not None:
        # a user's high-resolution exterior replaces the pieces' outer faces
        BV, BF, notes = read_exterior(inp.exterior)
        cf.notes.extend(notes)
    else:
        BV, BF = cf.exterior_V, cf.exterior_F
    ctx.products.update(coarse=cf, exterior=(BV, BF))
    save_coarse(ctx, cf)
    ctx.counts.update(components=cf.n_components, coarse_fracture_triangles=len(cf.F), frames=cf.n_frames)
    separated = cf.face_fracture_time < cf.n_frames
    ctx.stats["coarse"] = {
        "fit_residual_max": float(cf.fit_residual.max()),
        "separated_triangles": int(separated.sum()),
        "virtual_triangles": int(cf.virtual.sum()),
        "first_separation_frame": int(cf.face_fracture_time.min()) + 1 if separated.any() else None,
        "up_axis": cf.up_axis,
        # the input's frame numbers, frame rate and unit, which the outputs keep (null: the input did not say)
        "first_frame": cf.source.first_frame,
        "frame_step": cf.source.frame_step,
        "fps": cf.source.fps,
        "meters_per_unit": cf.source.meters_per_unit,
    }
    if "rigid_residual" in extra:
        ctx.stats["coarse"]["rigid_fit_residual_max"] = float(extra["rigid_residual"].max())
    ctx.notes.extend(f"coarse: {n}" for n in cf.notes)


def save_coarse(ctx: RunContext, cf: CoarseFracture) -> None:
    """Write the coarse stage's outputs (PLY meshes with labels, animation arrays)."""
    sp = cf.special()
    write_ply(ctx.path(layout.EXTERIOR), cf.exterior_V, cf.exterior_F,
              face_data={"component": cf.exterior_component})
    write_ply(ctx.path(layout.COARSE_SURFACE), cf.V, cf.F,
              vertex_data={"fracture_time": cf.vertex_fracture_time,
                           "boundary": sp.boundary_vertices.astype(np.uint8),
                           "nonmanifold": sp.nonmanifold_vertices.astype(np.uint8)},
              face_data={"side0": cf.sides[:, 0], "side1": cf.sides[:, 1], "fracture_time": cf.face_fracture_time,
                         "virtual": cf.virtual.astype(np.uint8)})
    ctx.save_array(layout.ANIMATION_LO, cf.animation.lo)
    ctx.save_array(layout.ANIMATION_HI, cf.animation.hi)
    ctx.save_array(layout.ANIMATION_NODES, cf.animation.nodes)
    ctx.save_array(layout.FIT_RESIDUAL, cf.fit_residual)
    ctx.save_json(layout.COMPONENTS, {"names": cf.names, "frames": cf.n_frames, "notes": cf.notes})

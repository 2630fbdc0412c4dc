"""The ``coarse`` stage: the coarse fracture animation in material space (Section 4.1)."""

from __future__ import annotations

import numpy as np

from fracture.coarse import CoarseFracture
from fracture.meshio import read_mesh
from fracture.mesh_sequence import load_coarse_sequence
from fracture.plyio import write_ply
from fracture.runner import RunContext, stage


@stage("coarse")
def coarse_stage(ctx: RunContext) -> None:
    inp = ctx.cfg["input"]
    if inp["kind"] != "mesh_sequence":
        return  # `meshes`: the fields stage reads the exterior and fracture files itself
    with ctx.bar(1, "coarse: import") as bar:
        cf, extra = load_coarse_sequence(inp["path"], inp["glob"], inp["lattice"], inp["separation"])
        bar.update()
    if inp["exterior"] is not None:  # a user's high-resolution exterior replaces the pieces' outer faces
        BV, BF = read_mesh(inp["exterior"], "input.exterior", closed=True)
    else:
        BV, BF = cf.exterior_V, cf.exterior_F
    ctx.products.update(coarse=cf, exterior=(BV, BF), coarse_fracture=(cf.V, cf.F))
    save_coarse(ctx, cf)
    ctx.counts.update(components=cf.n_components, coarse_fracture_triangles=int(len(cf.F)), frames=cf.n_frames)
    ctx.stats["coarse"] = {
        "fit_residual_max": float(cf.fit_residual.max()),
        "rigid_fit_residual_max": float(extra["rigid_residual"].max()),
        "separated_triangles": int((cf.face_fracture_time < cf.n_frames).sum()),
        "first_separation_frame": int(cf.face_fracture_time.min()) + 1,
    }
    ctx.notes.extend(f"coarse: {n}" for n in cf.notes)


def save_coarse(ctx: RunContext, cf: CoarseFracture) -> None:
    """Write the coarse stage's outputs (PLY meshes with labels, animation arrays)."""
    sp = cf.special()
    write_ply(ctx.path("coarse/exterior.ply"), cf.exterior_V, cf.exterior_F,
              face_data={"component": cf.exterior_component})
    write_ply(ctx.path("coarse/fracture_surface.ply"), cf.V, cf.F,
              vertex_data={"fracture_time": cf.vertex_fracture_time,
                           "boundary": sp.boundary_vertices.astype(np.uint8),
                           "nonmanifold": sp.nonmanifold_vertices.astype(np.uint8)},
              face_data={"side0": cf.sides[:, 0], "side1": cf.sides[:, 1], "fracture_time": cf.face_fracture_time,
                         "virtual": cf.virtual.astype(np.uint8)})
    ctx.save_array("coarse/animation_lo.npy", cf.animation.lo)
    ctx.save_array("coarse/animation_hi.npy", cf.animation.hi)
    ctx.save_array("coarse/animation_nodes.npy", cf.animation.nodes)
    ctx.save_array("coarse/fit_residual.npy", cf.fit_residual)
    ctx.save_json("coarse/components.json", {"names": cf.names, "frames": cf.n_frames, "notes": cf.notes})

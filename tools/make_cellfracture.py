"""Make coarse fracture animations with Blender's Cell Fracture add-on and rigid bodies.

Runs inside Blender (Debian's ``blender`` package, 3.4, ships the add-on)::

    blender -b --factory-startup --python tools/make_cellfracture.py -- --out examples/cellfracture
    blender -b --factory-startup --python tools/make_cellfracture.py -- --out /tmp/c --case torus_12 --frames 30
    blender -b --factory-startup --python tools/make_cellfracture.py -- --out /tmp/held --random 8 --random-seed 1

For every case (an object, a number of cells, a seed, a pose) it builds the
object, fractures it with Cell Fracture (cells seeded by random points inside
the object, noise, margin 0, the add-on's defaults otherwise), makes each
piece an active rigid body (convex hull, mass 1) over a passive ground plane,
lets them fall, and writes the frames three ways, as artists export them:

* ``CASE/sample/frame_0001.obj ...``: world coordinates, Z up, one ``o`` per
  piece, n-gons, indices global to the file (like ``examples/blender_cellfracture_cube8``);
* ``CASE/blender_obj/frameN.obj``: Blender's own OBJ exporter with its
  defaults (animation on, Y up, forward -Z, ``.mtl``, normals, UVs);
* ``CASE/ply/frame_0001.ply ...``: one ASCII PLY per frame, all pieces in one
  mesh, n-gons kept (as Blender's PLY export keeps them), Z up;
* ``CASE/usd/CASE.usdc``: Blender's USD exporter (animation on): one mesh per
  piece under its transform, the rigid motion as time-sampled transforms.

``CASE/case.json`` records the case, Blender's version and the export axes.
Everything is deterministic for a given Blender build (seeded point sets,
the rigid-body solver's fixed steps).
"""

import argparse
import json
import math
import random
import sys
from pathlib import Path

import bpy
import addon_utils
from mathutils import Euler, Matrix, Vector

# name: (primitive, cells, seed, rotation in degrees, height of the centre above the ground)
CASES = {
    "cube_rotated_8": ("cube", 8, 1, (20.0, 35.0, 10.0), 3.0),
    "cube_12": ("cube", 12, 2, (0.0, 0.0, 0.0), 3.0),
    "cube_20": ("cube", 20, 3, (0.0, 10.0, 45.0), 3.5),
    "cylinder_10": ("cylinder", 10, 4, (90.0, 0.0, 0.0), 3.0),
    "icosphere_10": ("icosphere", 10, 5, (0.0, 0.0, 0.0), 3.0),
    "icosphere_16": ("icosphere", 16, 6, (10.0, 0.0, 30.0), 3.5),
    "torus_8": ("torus", 8, 7, (30.0, 0.0, 0.0), 3.0),
    "torus_12": ("torus", 12, 8, (0.0, 0.0, 0.0), 3.0),
    "suzanne_10": ("suzanne", 10, 9, (0.0, 0.0, 0.0), 3.0),
    "suzanne_6": ("suzanne", 6, 10, (0.0, 0.0, 60.0), 3.0),
}


def _args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    ap = argparse.ArgumentParser(prog="make_cellfracture.py")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--case", action="append", choices=sorted(CASES), help="default: every case")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--formats", default=None, help="comma-separated, of " + ",".join(FORMATS) + " (default: every "
                    "one this Blender writes; Debian's Blender 3.4 has no USD exporter)")
    ap.add_argument("--random", type=int, default=0, metavar="N",
                    help="instead of the named cases, N random ones (object, cells, seed and pose drawn "
                         "with --random-seed): inputs the corpus has not seen")
    ap.add_argument("--random-seed", type=int, default=0)
    # settings artists change from the ones above (every case made with them)
    ap.add_argument("--margin", type=float, default=0.0,
                    help="Cell Fracture's margin: a gap of this size (before --scale) between the pieces")
    ap.add_argument("--noise", type=float, default=0.0, help="Cell Fracture's source noise (0-1)")
    ap.add_argument("--recursion", type=int, default=0,
                    help="Cell Fracture's recursion: fracture every piece again this many times (3 cells each)")
    ap.add_argument("--scale", type=float, default=1.0,
                    help="the whole scene this many times larger (other units: 100 for centimetres)")
    ap.add_argument("--stretch", default="1,1,1", help="the object scaled by x,y,z before it is fractured "
                    "(a plank: 3,0.4,0.25)")
    ap.add_argument("--offset", default="0,0,0", help="the whole scene moved by x,y,z (after --scale)")
    ap.add_argument("--with-ground", action="store_true",
                    help="export the ground plane with the pieces (as a scene exported whole, not its selection)")
    args = ap.parse_args(argv)
    args.stretch, args.offset = _vector(ap, "--stretch", args.stretch), _vector(ap, "--offset", args.offset)
    if args.scale <= 0.0 or min(args.stretch) <= 0.0 or args.margin < 0.0:
        ap.error("--scale and --stretch must be positive, --margin not negative")
    return args


def _vector(ap, flag: str, text: str) -> tuple:
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        v = ()
    if len(v) != 3:
        ap.error(f"{flag}: expected three numbers x,y,z, got {text!r}")
    return v


def random_cases(n: int, seed: int) -> dict:
    """``n`` cases drawn like the named ones: an object, 5 to 20 cells, a seed, any rotation."""
    rng = random.Random(seed)
    out = {}
    for _ in range(n):
        kind = rng.choice(["cube", "cylinder", "icosphere", "torus", "suzanne"])
        cells, cell_seed = rng.randint(5, 20), rng.randint(100, 10**6)
        rot = tuple(round(rng.uniform(0.0, 90.0), 1) for _ in range(3))
        out[f"{kind}_{cells}_s{cell_seed}"] = (kind, cells, cell_seed, rot, 3.5)
    return out


def _clear():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    addon_utils.enable("object_fracture_cell", default_set=True)


def _primitive(kind: str):
    if kind == "cube":
        bpy.ops.mesh.primitive_cube_add(size=2.0)
    elif kind == "cylinder":
        bpy.ops.mesh.primitive_cylinder_add(vertices=16, radius=1.0, depth=2.0)
    elif kind == "icosphere":
        bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2, radius=1.2)
    elif kind == "torus":
        bpy.ops.mesh.primitive_torus_add(major_segments=24, minor_segments=10, major_radius=1.0, minor_radius=0.4)
    elif kind == "suzanne":  # remeshed: Suzanne is open and self-intersecting, the voxel remesh closes it
        bpy.ops.mesh.primitive_monkey_add(size=2.0)
        obj = bpy.context.active_object
        mod = obj.modifiers.new("remesh", "REMESH")
        mod.mode, mod.voxel_size = "VOXEL", 0.12
        bpy.ops.object.modifier_apply(modifier=mod.name)
        bpy.ops.object.mode_set(mode="EDIT")
        bpy.ops.mesh.select_all(action="SELECT")
        bpy.ops.mesh.decimate(ratio=0.3)
        bpy.ops.object.mode_set(mode="OBJECT")
    else:
        raise ValueError(kind)
    return bpy.context.active_object


def _seed_points(obj, cells: int, seed: int):
    """A child point cloud of ``cells`` random points inside ``obj``'s bounding box (Cell Fracture's VERT_CHILD)."""
    rng = random.Random(seed)
    lo = Vector([min(v.co[i] for v in obj.data.vertices) for i in range(3)])
    hi = Vector([max(v.co[i] for v in obj.data.vertices) for i in range(3)])
    pts = [Vector([rng.uniform(0.8 * lo[i], 0.8 * hi[i]) for i in range(3)]) for _ in range(cells)]
    mesh = bpy.data.meshes.new("seeds")
    mesh.from_pydata([tuple(p) for p in pts], [], [])
    seeds = bpy.data.objects.new("seeds", mesh)
    bpy.context.scene.collection.objects.link(seeds)
    seeds.parent = obj
    return seeds


def build(spec: tuple, frames: int, settings=None):
    """The object of ``spec`` (an entry of :data:`CASES`) fractured, its pieces posed as rigid bodies;
    ``settings`` (the command line's) the margin, noise, recursion, scale, stretch and offset."""
    kind, cells, seed, rot, height = spec
    margin, noise, recursion = (0.0, 0.0, 0) if settings is None else (settings.margin, settings.noise,
                                                                       settings.recursion)
    scale, stretch, offset = (1.0, (1.0, 1.0, 1.0), (0.0, 0.0, 0.0)) if settings is None else (
        settings.scale, settings.stretch, settings.offset)
    _clear()
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, frames
    obj = _primitive(kind)
    obj.name = "source"
    if stretch != (1.0, 1.0, 1.0):
        obj.scale = stretch
        bpy.ops.object.transform_apply(location=False, rotation=False, scale=True)
    seeds = _seed_points(obj, cells, seed)
    bpy.ops.object.select_all(action="DESELECT")
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    # the recursion's pieces have no child points: they are cut at points of their own vertices
    source = {"VERT_CHILD", "VERT_OWN"} if recursion else {"VERT_CHILD"}
    bpy.ops.object.add_fracture_cell_objects(source=source, source_limit=cells, source_noise=noise,
                                             margin=margin, recursion=recursion, recursion_source_limit=3,
                                             use_recenter=True, use_remove_original=True,
                                             collection_name="", use_smooth_faces=False)
    bpy.data.objects.remove(seeds)
    if obj.name in scene.objects:  # the add-on leaves the original behind when its seeds are a child
        bpy.data.objects.remove(obj)
    pieces = sorted((o for o in scene.objects if o.type == "MESH"), key=lambda o: o.name)
    # pose the whole object: rotate about the origin, lift
    R = Euler([math.radians(a) for a in rot]).to_matrix().to_4x4()
    T = Matrix.Translation(Vector(offset) + Vector((0.0, 0.0, height * scale)))
    S = Matrix.Scale(scale, 4)
    for o in pieces:
        o.matrix_world = T @ S @ R @ o.matrix_world
    bpy.ops.object.select_all(action="DESELECT")
    for o in pieces:
        o.select_set(True)
    bpy.context.view_layer.objects.active = pieces[0]
    bpy.ops.object.transform_apply(location=False, rotation=True, scale=True)
    bpy.ops.rigidbody.world_add()
    world = scene.rigidbody_world
    world.point_cache.frame_start, world.point_cache.frame_end = 1, frames
    for o in pieces:
        bpy.context.view_layer.objects.active = o
        bpy.ops.rigidbody.object_add(type="ACTIVE")
        o.rigid_body.collision_shape = "CONVEX_HULL"
        o.rigid_body.mass = 1.0
        # the pieces touch: Bullet's default 4 cm collision margin would make them overlap and burst apart
        o.rigid_body.use_margin = True
        o.rigid_body.collision_margin = 0.0
    return pieces


def build_with_ground(spec: tuple, frames: int, settings=None):
    """The fractured object's pieces as active rigid bodies over a passive ground plane at z = 0 (moved
    and scaled with the scene by ``settings``)."""
    pieces = build(spec, frames, settings)
    scene = bpy.context.scene
    scale, offset = (1.0, (0.0, 0.0, 0.0)) if settings is None else (settings.scale, settings.offset)
    bpy.ops.mesh.primitive_plane_add(size=40.0 * scale, location=offset)
    ground = bpy.context.active_object
    ground.name = "ground"
    bpy.ops.rigidbody.object_add(type="PASSIVE")
    ground.hide_render = True
    scene.frame_set(1)
    return pieces, ground


def _world_polygons(o):
    M = o.matrix_world
    dg = bpy.context.evaluated_depsgraph_get()
    ev = o.evaluated_get(dg)
    me = ev.to_mesh()
    V = [tuple(M @ v.co) for v in me.vertices]
    P = [tuple(p.vertices) for p in me.polygons]
    ev.to_mesh_clear()
    return V, P


def write_sample_obj(path: Path, pieces, frame: int):
    lines = [f"# frame {frame}"]
    base = 1
    for o in pieces:
        V, P = _world_polygons(o)
        lines.append(f"o {o.name}")
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in V]
        lines += ["f " + " ".join(str(base + i) for i in p) for p in P]
        base += len(V)
    path.write_text("\n".join(lines) + "\n")


def write_ply(path: Path, pieces, frame: int):
    Vs, Ps, base = [], [], 0
    for o in pieces:
        V, P = _world_polygons(o)
        Vs += V
        Ps += [tuple(base + i for i in p) for p in P]
        base += len(V)
    head = ["ply", "format ascii 1.0", f"comment frame {frame}", f"element vertex {len(Vs)}",
            "property float x", "property float y", "property float z", f"element face {len(Ps)}",
            "property list uchar uint vertex_indices", "end_header"]
    body = [f"{x:.6f} {y:.6f} {z:.6f}" for x, y, z in Vs] + [f"{len(p)} " + " ".join(map(str, p)) for p in Ps]
    path.write_text("\n".join(head + body) + "\n")


FORMATS = ("sample", "blender_obj", "ply", "usd")


def _formats(asked: str | None) -> set:
    """The formats to write: ``asked`` checked against what this Blender can write."""
    usd = "usd_export" in dir(bpy.ops.wm)  # the registered operators (a missing one fails only when called)
    if asked is None:
        return {f for f in FORMATS if f != "usd" or usd}
    formats = set(asked.split(","))
    unknown = formats - set(FORMATS)
    if unknown:
        sys.exit(f"make_cellfracture.py: --formats: unknown {', '.join(sorted(unknown))}; expected some of "
                 f"{', '.join(FORMATS)}")
    if "usd" in formats and not usd:
        sys.exit(f"make_cellfracture.py: --formats usd: Blender {bpy.app.version_string} has no USD exporter "
                 "(Debian's build leaves it out); leave usd out, or run a Blender with USD")
    return formats


def main():
    args = _args()
    formats = _formats(args.formats)
    cases = random_cases(args.random, args.random_seed) if args.random else CASES
    names = sorted(cases) if args.random else args.case or sorted(CASES)
    for case in names:
        pieces, ground = build_with_ground(cases[case], args.frames, args)
        exported = pieces + [ground] if args.with_ground else pieces
        out = args.out / case
        scene = bpy.context.scene
        for sub in formats:
            (out / sub).mkdir(parents=True, exist_ok=True)
        for f in range(1, args.frames + 1):
            scene.frame_set(f)
            if "sample" in formats:
                write_sample_obj(out / "sample" / f"frame_{f:04d}.obj", exported, f)
            if "ply" in formats:
                write_ply(out / "ply" / f"frame_{f:04d}.ply", exported, f)
        if "blender_obj" in formats:
            bpy.ops.object.select_all(action="DESELECT")
            for o in exported:
                o.select_set(True)
            scene.frame_set(1)
            bpy.ops.wm.obj_export(filepath=str(out / "blender_obj" / "frame.obj"), export_animation=True,
                                  start_frame=1, end_frame=args.frames, export_selected_objects=True)
        if "usd" in formats:
            bpy.ops.object.select_all(action="DESELECT")
            for o in exported:
                o.select_set(True)
            scene.frame_set(1)
            bpy.ops.wm.usd_export(filepath=str(out / "usd" / f"{case}.usdc"), selected_objects_only=True,
                                  export_animation=True, export_materials=False)
        kind, cells, seed, rot, height = cases[case]
        (out / "case.json").write_text(json.dumps({
            "case": case, "object": kind, "cells": cells, "pieces": len(pieces), "seed": seed,
            "rotation_degrees": rot, "height": height, "frames": args.frames,
            "margin": args.margin, "noise": args.noise, "recursion": args.recursion, "scale": args.scale,
            "stretch": args.stretch, "offset": args.offset, "with_ground": args.with_ground,
            "blender": bpy.app.version_string,
            "formats": {k: v for k, v in {
                "sample": "Z up, world coordinates, n-gons", "blender_obj": "Blender's OBJ exporter defaults: Y up, "
                "forward -Z", "ply": "ASCII, Z up, all pieces in one mesh, n-gons",
                "usd": "Blender's USD exporter: time-sampled transforms, Z up"}.items() if k in formats},
        }, indent=1))
        print(f"{case}: {len(pieces)} pieces, {args.frames} frames -> {out}")


main()

"""A coarse fracture animation as Blender writes it to USD: pieces under time-sampled transforms.

Runs in Blender 4.2 or later as a Python module (``bpy``, installed by ``make install`` into
``.venv-blender``), since Debian's Blender 3.4 has no USD exporter:

    .venv-blender/bin/python tools/make_usd_animation.py REST.obj OUT.usdc [--frames 24]

REST.obj holds the pieces of a fractured object in its rest pose, one ``o`` per piece (e.g. the
first frame of a Cell Fracture export of ``tools/make_cellfracture.py``). Each piece gets its origin
at its centre and becomes an active rigid body (convex hull, mass 1, no collision margin) over a
passive ground plane at z = 0 (not exported); the simulation is stepped frame by frame and written
by Blender's USD exporter with animation on: one mesh per piece, its rest points once, its motion as
time-sampled transforms, Z up.
"""

import argparse
import sys

import bpy


def main() -> None:
    ap = argparse.ArgumentParser(prog="make_usd_animation.py")
    ap.add_argument("rest", help="OBJ of the pieces in their rest pose (Z up)")
    ap.add_argument("out", help="USD file to write")
    ap.add_argument("--frames", type=int, default=24)
    args = ap.parse_args(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:])
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, args.frames
    bpy.ops.wm.obj_import(filepath=args.rest, forward_axis="Y", up_axis="Z")
    pieces = sorted((o for o in scene.objects if o.type == "MESH"), key=lambda o: o.name)
    bpy.ops.object.select_all(action="DESELECT")
    for o in pieces:
        o.select_set(True)
    bpy.context.view_layer.objects.active = pieces[0]
    bpy.ops.object.origin_set(type="ORIGIN_GEOMETRY", center="BOUNDS")
    bpy.ops.rigidbody.world_add()
    scene.rigidbody_world.point_cache.frame_start = 1
    scene.rigidbody_world.point_cache.frame_end = args.frames
    for o in pieces:
        bpy.context.view_layer.objects.active = o
        bpy.ops.rigidbody.object_add(type="ACTIVE")
        o.rigid_body.collision_shape = "CONVEX_HULL"
        o.rigid_body.mass = 1.0
        o.rigid_body.use_margin = True
        o.rigid_body.collision_margin = 0.0
    bpy.ops.mesh.primitive_plane_add(size=40.0, location=(0.0, 0.0, 0.0))
    ground = bpy.context.active_object
    bpy.ops.rigidbody.object_add(type="PASSIVE")
    for f in range(1, args.frames + 1):  # the simulation runs as the frames are stepped in order
        scene.frame_set(f)
    bpy.ops.object.select_all(action="DESELECT")
    for o in pieces:
        o.select_set(True)
    ground.select_set(False)
    scene.frame_set(1)
    bpy.ops.wm.usd_export(filepath=args.out, selected_objects_only=True, export_animation=True,
                          export_materials=False)
    print(f"{len(pieces)} pieces, {args.frames} frames -> {args.out}")


main()

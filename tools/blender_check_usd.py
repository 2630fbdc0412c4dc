"""Import a fracref USD file (or one OBJ frame) into Blender (``bpy``) and print what Blender sees, as JSON.

Runs inside Blender's Python: ``python tools/blender_check_usd.py FILE.usdc`` with
the ``bpy`` module, or ``blender -b --factory-startup --python tools/blender_check_usd.py -- FILE.usdc``.
Prints one JSON object: Blender's version, the scene's frame range and, per
imported mesh object, its name, vertex and face counts, whether every edge has
exactly two faces (closed), the material name of each face (counts), and the
world-space vertex positions at the first and last frames (evaluated, so the
time-sampled points are applied).
"""

import json
import sys

import bpy
import numpy as np


def _args() -> list[str]:
    argv = sys.argv
    return argv[argv.index("--") + 1:] if "--" in argv else argv[1:]


def _positions(obj, depsgraph) -> np.ndarray:
    ev = obj.evaluated_get(depsgraph)
    mesh = ev.to_mesh()
    co = np.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    M = np.array(ev.matrix_world)
    X = co.reshape(-1, 3) @ M[:3, :3].T + M[:3, 3]
    ev.to_mesh_clear()
    return X


def main() -> None:
    path = _args()[0]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    if path.lower().endswith(".obj"):  # our frames are Z up, as Blender's scene is
        bpy.ops.wm.obj_import(filepath=path, forward_axis="Y", up_axis="Z")
    else:
        bpy.ops.wm.usd_import(filepath=path)
    scene = bpy.context.scene
    out = {"blender": bpy.app.version_string, "frame_start": scene.frame_start, "frame_end": scene.frame_end,
           "objects": []}
    meshes = sorted((o for o in scene.objects if o.type == "MESH"), key=lambda o: o.name)
    frames = {}
    for f in (scene.frame_start, scene.frame_end):
        scene.frame_set(f)
        dg = bpy.context.evaluated_depsgraph_get()
        frames[f] = {o.name: _positions(o, dg) for o in meshes}
    for o in meshes:
        me = o.data
        edge_faces = {}
        for poly in me.polygons:
            for k in poly.edge_keys:
                edge_faces[k] = edge_faces.get(k, 0) + 1
        materials = {}
        for poly in me.polygons:
            slot = o.material_slots[poly.material_index] if o.material_slots else None
            name = slot.material.name if slot and slot.material else ""
            materials[name] = materials.get(name, 0) + 1
        out["objects"].append({
            "name": o.name, "vertices": len(me.vertices), "faces": len(me.polygons),
            "closed": all(c == 2 for c in edge_faces.values()),
            "materials": materials,
            "first": frames[scene.frame_start][o.name].tolist(),
            "last": frames[scene.frame_end][o.name].tolist(),
        })
    print("FRACREF-JSON " + json.dumps(out))


main()

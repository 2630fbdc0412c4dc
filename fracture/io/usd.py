"""The animated pieces as one USD file (usd-core), for Blender, Houdini and any USD pipeline.

Layout of the stage::

    /Fracture                      Xform, the default prim
        /Materials/interior        UsdPreviewSurface, the fracture faces
        /Materials/exterior        UsdPreviewSurface, the object's surface B
        /<piece>                   Mesh per piece, named after the coarse piece
            interior, exterior     GeomSubsets (family materialBind) bound to the materials

Each mesh holds its topology once (``faceVertexCounts``, ``faceVertexIndices``)
and its points time-sampled per frame; ``extent`` is time-sampled with them.
The piece's name as the input gave it is kept in the string attribute
``fracref:sourceName`` (USD prim names allow only letters, digits and ``_``).
The stage records its up axis, ``metersPerUnit``, the frame range (frames
numbered from ``start_frame``, as the coarse input was) and the frame rate.

The file is written next to its destination under a temporary name and moved
over it, so a failed write never leaves half a file behind.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

# Colours of the two materials (linear RGB): pale stone outside, a darker, warmer break inside.
_COLOURS = {"exterior": (0.62, 0.62, 0.60), "interior": (0.55, 0.35, 0.25)}


def prim_name(name: str, taken: set[str]) -> str:
    """A valid USD prim name for ``name``, unique among ``taken`` (which it joins)."""
    base = re.sub(r"[^A-Za-z0-9_]", "_", name) or "piece"
    if base[0].isdigit():
        base = "_" + base
    out, k = base, 1
    while out in taken:
        out, k = f"{base}_{k}", k + 1
    taken.add(out)
    return out


def write_pieces_usd(path: str | Path, names: Sequence[str], faces: Sequence[np.ndarray],
                     exterior: Sequence[np.ndarray], frames: Iterable[Sequence[np.ndarray]], *,
                     start_frame: int = 1, fps: float = 24.0, up_axis: str = "Z",
                     meters_per_unit: float = 1.0) -> Path:
    """Write the pieces and their animation to ``path`` (``.usd``, ``.usdc`` or ``.usda``).

    Parameters
    ----------
    names : piece names, one per piece.
    faces : per piece, its triangles ``(m, 3)`` into that piece's points.
    exterior : per piece, a bool ``(m,)``: the triangle lies on the object's surface B.
    frames : per frame, a sequence of every piece's points ``(n_c, 3)``.

    Returns the path written.
    """
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt

    path = Path(path)
    if up_axis not in ("Y", "Z"):
        raise ValueError(f"up_axis must be 'Y' or 'Z', got {up_axis!r}")
    if not (len(names) == len(faces) == len(exterior)):
        raise ValueError(f"{len(names)} names, {len(faces)} face arrays and {len(exterior)} exterior flags")
    tmp = path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix}")
    try:
        stage = Usd.Stage.CreateNew(str(tmp))
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis == "Y" else UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
        stage.SetTimeCodesPerSecond(fps)
        stage.SetFramesPerSecond(fps)
        root = UsdGeom.Xform.Define(stage, "/Fracture")
        stage.SetDefaultPrim(root.GetPrim())

        materials = {}
        UsdGeom.Scope.Define(stage, "/Fracture/Materials")
        for kind, colour in _COLOURS.items():
            mat = UsdShade.Material.Define(stage, f"/Fracture/Materials/{kind}")
            shader = UsdShade.Shader.Define(stage, f"/Fracture/Materials/{kind}/surface")
            shader.CreateIdAttr("UsdPreviewSurface")
            shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*colour))
            shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.8 if kind == "interior" else 0.6)
            mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
            materials[kind] = mat

        taken: set[str] = {"Materials"}
        meshes = []
        for name, F, ext in zip(names, faces, exterior):
            F = np.asarray(F, np.int32)
            ext = np.asarray(ext, bool)
            mesh = UsdGeom.Mesh.Define(stage, f"/Fracture/{prim_name(str(name), taken)}")
            mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
            mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(F), 3, np.int32)))
            mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(F.ravel())))
            mesh.GetPrim().CreateAttribute("fracref:sourceName", Sdf.ValueTypeNames.String).Set(str(name))
            UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
            for kind, which in (("interior", ~ext), ("exterior", ext)):
                subset = UsdGeom.Subset.CreateGeomSubset(
                    mesh, kind, UsdGeom.Tokens.face, Vt.IntArray.FromNumpy(np.flatnonzero(which).astype(np.int32)),
                    familyName=UsdShade.Tokens.materialBind)
                UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(materials[kind])
            UsdGeom.Subset.SetFamilyType(mesh, UsdShade.Tokens.materialBind, UsdGeom.Tokens.partition)
            meshes.append(mesh)

        t = start_frame - 1
        for t, X in enumerate(frames, start=start_frame):
            if len(X) != len(meshes):
                raise ValueError(f"frame {t}: {len(X)} point arrays for {len(meshes)} pieces")
            for mesh, P in zip(meshes, X):
                P = np.ascontiguousarray(P, np.float32)
                mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(P), t)
                lo, hi = P.min(axis=0), P.max(axis=0)
                mesh.GetExtentAttr().Set(Vt.Vec3fArray([Gf.Vec3f(*lo.tolist()), Gf.Vec3f(*hi.tolist())]), t)
        if t < start_frame:
            raise ValueError("no frames to write")
        stage.SetStartTimeCode(start_frame)
        stage.SetEndTimeCode(t)
        stage.GetRootLayer().Save()
        del stage
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path

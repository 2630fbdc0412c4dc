"""The animated pieces as one USD file (usd-core), for Blender, Houdini and any USD pipeline.

Layout of the stage::

    /Fracture                      Xform, the default prim
        /Materials/interior        UsdPreviewSurface, the fracture faces
        /Materials/exterior        UsdPreviewSurface, the object's surface B
        /<piece>                   Xform per piece, named after the coarse piece; its transform time-sampled
            /<piece>               Mesh: the piece in material space (named as its Xform: Blender merges
                                   the two into one object, named after the mesh)
                interior, exterior GeomSubsets (family materialBind, a partition) bound to the materials

A piece that moves rigidly (every frame's points within :data:`RIGID` of the
scene's size of a rotation and translation of its material-space points,
as the pieces of a rigid-body simulation do) is written once: its points
are the mesh's default value and each frame is a sample of its Xform's
``xformOp:transform``, a few hundred bytes. At the frames where it deforms
(soft scenes) the mesh's points carry the frame's positions and the
transform is the identity; ``extent`` follows the points. Each piece's
name as the input gave it is the Xform's string attribute
``fracref:sourceName`` and the mesh's constant primitive variable
``piecename`` (what Houdini's RBD tools tie a piece to its transforms by);
USD prim names allow only letters, digits and ``_``. The stage records its
up axis, ``metersPerUnit``, ``timeCodesPerSecond`` and the frame range
(frames numbered from ``start_frame``, as the coarse input was).

The file is written next to its destination under a temporary name and moved
over it, so a failed write never leaves half a file behind.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from fracture.io.atomic import OutputError, left_by_dead_writers

# A piece whose points at a frame are within this of a rotation and translation of its rest points (relative
# to the scene's size) moves rigidly at that frame: its transform is written, not its points. Rigid-body
# pieces come out of the transfer exact to rounding (1e-15); the positions are checked to 1e-6.
RIGID = 1e-7
# Colours of the two materials (linear RGB): pale stone outside, a darker, warmer break inside.
_COLOURS = {"exterior": (0.62, 0.62, 0.60), "interior": (0.55, 0.35, 0.25)}


def usd_problem(exc: Exception) -> str:
    """What a USD error (``pxr.Tf.ErrorException``) says, in one line: its first message (USD reports the
    deepest cause first), without USD's source locations and internal namespaces."""
    text = str(exc)
    messages = []
    for chunk in text.split("Error in ")[1:] or [text]:
        head, sep, message = chunk.partition(" : '")
        message = (message if sep else head).strip().rstrip("'").strip()
        message = re.sub(r"pxrInternal_v\w+?__pxrReserved__::", "", message)
        if message and message not in messages:
            messages.append(" ".join(message.split()))
    useful = [m for m in messages if not m.startswith("Failed to open layer")] or messages
    return useful[0] if useful else type(exc).__name__


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


def rigid_motion(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The rotation ``R`` and translation ``T`` taking points ``X`` nearest to ``Y`` (Kabsch), and the
    largest distance of ``R X + T`` from ``Y``."""
    cx, cy = X.mean(axis=0), Y.mean(axis=0)
    U, _, Vt = np.linalg.svd((X - cx).T @ (Y - cy))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    T = cy - R @ cx
    return R, T, float(np.sqrt(((X @ R.T + T - Y) ** 2).sum(axis=1).max(initial=0.0)))


def usd_timing(configured_fps: float | None, first_frame: float | None = None, frame_step: float | None = None,
               fps: float | None = None, meters_per_unit: float | None = None) -> dict:
    """:func:`write_pieces_usd`'s clock and unit for an animation the input numbered from ``first_frame`` every
    ``frame_step`` at ``fps`` in ``meters_per_unit`` (None: the input did not say): the frame rate configured,
    else the input's, else 24; a unit of a metre where the input gave none."""
    return dict(start_frame=1.0 if first_frame is None else float(first_frame),
                frame_step=1.0 if frame_step is None else float(frame_step),
                fps=float(configured_fps or fps or 24.0),
                meters_per_unit=1.0 if meters_per_unit is None else float(meters_per_unit))


def run_usd_timing(config: dict, manifest: dict) -> dict:
    """:func:`usd_timing` of a finished run: its config's ``animate.fps`` and its manifest's
    ``stats.coarse`` (the input's frame numbers, frame rate and unit; older runs say none)."""
    coarse = manifest.get("stats", {}).get("coarse", {})
    return usd_timing((config.get("animate") or {}).get("fps"),
                      **{k: coarse.get(k) for k in ("first_frame", "frame_step", "fps", "meters_per_unit")})


def write_pieces_usd(path: str | Path, names: Sequence[str], faces: Sequence[np.ndarray],
                     exterior: Sequence[np.ndarray], frames: Iterable[Sequence[np.ndarray]], *,
                     rest: Sequence[np.ndarray] | None = None, size: float | None = None,
                     start_frame: float = 1, frame_step: float = 1, fps: float = 24.0, up_axis: str = "Z",
                     meters_per_unit: float = 1.0) -> Path:
    """Write the pieces and their animation to ``path`` (``.usd``, ``.usdc`` or ``.usda``).

    Parameters
    ----------
    names : piece names, one per piece.
    faces : per piece, its triangles ``(m, 3)`` into that piece's points.
    exterior : per piece, a bool ``(m,)``: the triangle lies on the object's surface B.
    frames : per frame, a sequence of every piece's points ``(n_c, 3)``.
    rest : per piece, its material-space points (the mesh's own points, which each frame's rigid
        motion moves); without it every frame's points are written.
    size : the scene's size, for the rigid test (default: the first frame's box diagonal).
    start_frame, frame_step : the time code of the first frame and between frames (as the input numbered them).
    fps : time codes per second.
    meters_per_unit : the unit of the points, in metres.

    Returns the path written.
    """
    from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdShade, Vt

    path = Path(path)
    if up_axis not in ("Y", "Z"):
        raise ValueError(f"up_axis must be 'Y' or 'Z', got {up_axis!r}")
    if not (len(names) == len(faces) == len(exterior)) or (rest is not None and len(rest) != len(names)):
        raise ValueError(f"{len(names)} names, {len(faces)} face arrays and {len(exterior)} exterior flags"
                         + ("" if rest is None else f", {len(rest)} rest point arrays"))
    tmp = path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix}")
    _remove_stale_partials(path)

    def vec3f(P: np.ndarray):
        return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(P, np.float32))

    def extent(P: np.ndarray):
        lo, hi = P.min(axis=0), P.max(axis=0)
        return Vt.Vec3fArray([Gf.Vec3f(*lo.tolist()), Gf.Vec3f(*hi.tolist())])

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
        meshes, moves = [], []
        for c, (name, F, ext) in enumerate(zip(names, faces, exterior)):
            F = np.asarray(F, np.int32)
            ext = np.asarray(ext, bool)
            xform = UsdGeom.Xform.Define(stage, f"/Fracture/{prim_name(str(name), taken)}")
            xform.GetPrim().CreateAttribute("fracref:sourceName", Sdf.ValueTypeNames.String).Set(str(name))
            moves.append(xform.AddTransformOp())
            mesh = UsdGeom.Mesh.Define(stage, xform.GetPath().AppendChild(xform.GetPath().name))
            mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
            mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(F), 3, np.int32)))
            mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(F.ravel())))
            UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("piecename", Sdf.ValueTypeNames.String,
                                                    UsdGeom.Tokens.constant).Set(str(name))
            if rest is not None:
                mesh.CreatePointsAttr(vec3f(rest[c]))
                mesh.CreateExtentAttr(extent(np.asarray(rest[c])))
            UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
            for kind, which in (("interior", ~ext), ("exterior", ext)):
                subset = UsdGeom.Subset.CreateGeomSubset(
                    mesh, kind, UsdGeom.Tokens.face, Vt.IntArray.FromNumpy(np.flatnonzero(which).astype(np.int32)),
                    familyName=UsdShade.Tokens.materialBind)
                UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(materials[kind])
            UsdGeom.Subset.SetFamilyType(mesh, UsdShade.Tokens.materialBind, UsdGeom.Tokens.partition)
            meshes.append(mesh)

        if not frame_step > 0:
            raise ValueError(f"frame_step must be positive, got {frame_step}")
        t = before = None
        deformed = [False] * len(meshes)  # the piece's points at the frame before are not its rest points
        for k, X in enumerate(frames):
            before, t = t, start_frame + k * frame_step
            if len(X) != len(meshes):
                raise ValueError(f"frame {t:g}: {len(X)} point arrays for {len(meshes)} pieces")
            if size is None:
                every = np.concatenate([np.asarray(P) for P in X])
                size = float(np.linalg.norm(every.max(axis=0) - every.min(axis=0))) if len(every) else 1.0
            for c, (mesh, P) in enumerate(zip(meshes, X)):
                P = np.asarray(P, np.float64)
                M = Gf.Matrix4d(1.0)
                rigid = False
                if rest is not None and len(P):
                    R, T, gap = rigid_motion(np.asarray(rest[c], np.float64), P)
                    rigid = gap <= RIGID * size
                if rigid:  # row vectors: p' = p M, the translation in the last row
                    M = Gf.Matrix4d(*np.block([[R.T, np.zeros((3, 1))], [T[None], np.ones((1, 1))]]).ravel().tolist())
                    if deformed[c]:
                        mesh.GetPointsAttr().Set(vec3f(rest[c]), t)
                        mesh.GetExtentAttr().Set(extent(np.asarray(rest[c])), t)
                else:
                    if not deformed[c] and rest is not None and before is not None:
                        # the rest points until the frame before (a first sample would be held back to the start)
                        mesh.GetPointsAttr().Set(vec3f(rest[c]), before)
                        mesh.GetExtentAttr().Set(extent(np.asarray(rest[c])), before)
                    mesh.GetPointsAttr().Set(vec3f(P), t)
                    mesh.GetExtentAttr().Set(extent(P), t)
                deformed[c] = not rigid
                moves[c].Set(M, t)
        if t is None:
            raise ValueError("no frames to write")
        stage.SetStartTimeCode(start_frame)
        stage.SetEndTimeCode(t)
        stage.GetRootLayer().Save()
        del stage
        os.replace(tmp, path)
    except Tf.ErrorException as exc:  # a full disk, a folder one may not write in: said of the user's file
        raise OutputError(f"{path}: cannot write the USD file: {usd_problem(exc)}") from None
    except OSError as exc:
        raise OutputError(f"{path}: cannot write the USD file: {exc.strerror or exc}") from None
    finally:
        tmp.unlink(missing_ok=True)
    return path


def _remove_stale_partials(path: Path) -> None:
    """Delete the files ``.STEM.partial-PID.SUFFIX`` beside ``path`` that a killed writer left; those of a
    writer still going stay."""
    for stale in left_by_dead_writers(path.parent, f".{path.stem}.partial-", path.suffix):
        stale.unlink(missing_ok=True)

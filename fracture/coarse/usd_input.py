"""A coarse fracture animation from one USD file (Blender 4/5, Houdini), read with usd-core.

Every ``Mesh`` prim is a piece; its points in world space at each frame are its points there
(time-sampled or not) under its transforms there (time-sampled or not): Blender writes rest
points and time-sampled transforms, Houdini often time-sampled points. A mesh whose
``orientation`` is ``leftHanded`` (Houdini's default: its faces wind clockwise seen from outside)
has its faces turned. A point instancer's instances are pieces too: each mesh of the prototype an
instance shows, where the instance puts it (Houdini may write packed fragments so). The frames are the stage's integer time codes from its start to its end
(with no range authored, over the span of the points' and transforms' time samples).
The result holds the list of :class:`~fracture.coarse.mesh_sequence.MeshFrame` that a folder of OBJ
frames gives, so the same import follows (:func:`fracture.coarse.mesh_sequence.coarse_from_frames`),
with what the outputs keep of the stage: its up axis, time codes per second and ``metersPerUnit``.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fracture.errors import InputError
from fracture.coarse.mesh_sequence import MeshFrame, split_one_object
from fracture.io.usd import usd_problem

# Frames read at most: a time code range set by mistake (an end of 1e6) would read for hours.
MOST_FRAMES = 10_000


def _piece_name(prim) -> str:
    """Blender writes ``/root/NAME/NAME`` (a transform holding its mesh): the transform's name then."""
    parent = prim.GetParent()
    if parent and parent.GetName() == prim.GetName():
        return parent.GetName()
    return prim.GetName()


def _piece_names(prims) -> list[str]:
    """Every mesh's piece name (:func:`_piece_name`); meshes that share a name (``/geo/NAME/mesh``, as
    instanced pieces are written) take their parent's, and any still shared, their paths."""
    names = [_piece_name(p) for p in prims]
    for other in (lambda p: p.GetParent().GetName(), lambda p: str(p.GetPath()).strip("/")):
        count = Counter(names)
        names = [other(p) if count[n] > 1 else n for p, n in zip(prims, names)]
    return names


class UsdAnimation(NamedTuple):
    """What a USD file gives the import."""

    frames: list[MeshFrame]  # each with its time code
    up_axis: str  # "y" or "z"
    fps: float  # the stage's time codes per second
    meters_per_unit: float  # the stage's metersPerUnit (USD's own default, 0.01, where it says none)
    hidden: tuple[str, ...] = ()  # the paths of meshes left out: invisible, or for guides or proxies only


def read_usd_frames(path: str | Path) -> UsdAnimation:
    """The frames of a USD animation, its up axis, frame rate and unit.

    Raises
    ------
    InputError
        The file cannot be opened, holds no mesh, or a piece's faces change
        between frames, name the file, piece and frame. Meshes that share a
        name are told apart by their parents' names, else their paths.
    """
    from pxr import Tf, Usd, UsdGeom

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: USD file not found")
    if path.suffix.lower() == ".abc":
        raise InputError(f"{path}: an Alembic file; this reads USD (.usd, .usda, .usdc, .usdz): export the animation "
                         "as USD (Blender: File > Export > Universal Scene Description; Houdini: a USD ROP) or as "
                         "OBJ frames (input.kind: mesh_sequence)")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: the file is empty; expected a USD file (.usd, .usda, .usdc or .usdz)")
    try:
        stage = Usd.Stage.Open(str(path))
    except Tf.ErrorException as exc:
        raise InputError(f"{path}: cannot open as USD: {usd_problem(exc)}") from None
    problems = stage.GetCompositionErrors()  # USD skips a sublayer or reference it cannot open, and goes on
    if problems:
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        problem = str(problems[0]).strip().removesuffix("; skipping.").rstrip(".")
        raise InputError(f"{path}: {problem}{more}; expected every layer and reference it names beside it (copy them "
                         "with it, or flatten the stage: usdcat --flatten)")
    # instanced pieces (instanceable references, as Houdini may write packed fragments) are walked into
    found = [p for p in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies()) if p.IsA(UsdGeom.Mesh)]
    if not found:
        raise InputError(f"{path}: no Mesh prims: expected one mesh per piece")
    # what a renderer would not show is not a piece: the object Cell Fracture hid, a proxy or a guide
    shown = [_shown(p) for p in found]
    meshes = [p for p, s in zip(found, shown) if s]
    hidden = tuple(str(p.GetPath()) for p, s in zip(found, shown) if not s)
    if not meshes:
        raise InputError(f"{path}: every Mesh prim is invisible or a guide or proxy ({', '.join(hidden[:3])}"
                         f"{', ...' if len(hidden) > 3 else ''}): expected one visible mesh per piece")
    # a point instancer's instances of its prototypes are pieces (Houdini may write packed fragments so):
    # each mesh of the prototype an instance shows, where the instance puts it
    instanced = _instanced(stage, meshes)
    kept = {p.GetPath() for p in instanced.under}
    meshes = [p for p in meshes if p.GetPath() not in kept]
    names = _piece_names(meshes) + instanced.names
    pieces = [(p, None) for p in meshes] + instanced.pieces
    if not pieces:
        raise InputError(f"{path}: its meshes are the prototypes of point instancers with no instances: expected "
                         "one mesh or instance per piece")
    meshes = [p for p, _ in pieces]
    sampled = sorted(set(_sample_times(meshes)) | instanced.times)
    if stage.HasAuthoredTimeCodeRange():
        start, end = stage.GetStartTimeCode(), stage.GetEndTimeCode()
        what = f"its time code range {start:g} to {end:g}"
    elif sampled:  # animated, with no range authored: the span of the samples
        start, end = sampled[0], sampled[-1]
        what = f"its time samples ({start:g} to {end:g}; no time code range is authored)"
    else:  # no animation: one frame, the default values
        start = end = what = None
    if what is None:
        times = [Usd.TimeCode.Default()]
    else:
        first, last = int(np.floor(start)), int(np.floor(end))
        if last < first:
            raise InputError(f"{path}: {what} holds no frame; expected a start time code at or before its end")
        if last - first + 1 > MOST_FRAMES:
            raise InputError(f"{path}: {what} holds {last - first + 1:,} frames; expected at most {MOST_FRAMES:,} "
                             "(set the stage's start and end time codes to the frames of the fracture)")
        times = [Usd.TimeCode(float(t)) for t in range(first, last + 1)]
    topology = []
    for p, name in zip(meshes, names):
        mesh = UsdGeom.Mesh(p)
        # the faces at the default time, or at the first frame where only time samples hold them (as Houdini may
        # write them)
        counts = np.asarray(_at_default_or(mesh.GetFaceVertexCountsAttr(), times[0]) or [], np.int64)
        idx = np.asarray(_at_default_or(mesh.GetFaceVertexIndicesAttr(), times[0]) or [], np.int64)
        if counts.size == 0 or counts.sum() != idx.size or (counts < 3).any():
            raise InputError(f"{path}: piece {name!r} ({p.GetPath()}) has no faces or inconsistent face counts "
                             "(faceVertexCounts and faceVertexIndices); expected polygons of 3 or more corners")
        if idx.min() < 0:
            raise InputError(f"{path}: piece {name!r} ({p.GetPath()}): a face uses point {idx.min()}; expected "
                             "point indices from 0")
        if mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded:  # each face's corners reversed
            ends = np.cumsum(counts)
            k = np.arange(idx.size) - np.repeat(ends - counts, counts)  # corner k of its face
            idx = idx[np.repeat(ends, counts) - 1 - k]
        topology.append((counts, idx))
    cache = UsdGeom.XformCache()
    frames = []
    first_counts: dict[str, int] = {}  # each piece's points at the first frame
    for t in times:
        when = "the default time" if t.IsDefault() else f"frame {t.GetValue():g}"  # a stage without time samples
        cache.SetTime(t)
        V, polys, offset = [], [], 0
        placed = {}  # each instancer's instance transforms at this time
        for (p, instance), name, (counts, idx) in zip(pieces, names, topology):
            mesh = UsdGeom.Mesh(p)
            P = mesh.GetPointsAttr().Get(t)
            if P is None:
                raise InputError(f"{path}: piece {name!r} ({p.GetPath()}) has no points at {when}: expected time "
                                 "samples or a default value of its points")
            P = np.asarray(P, np.float64).reshape(-1, 3)
            if idx.max() >= len(P):
                raise InputError(f"{path}: piece {name!r} at {when}: a face uses point {idx.max()} of {len(P)}")
            if first_counts.setdefault(name, len(P)) != len(P):
                raise InputError(f"{path}: piece {name!r} has {len(P)} points at {when}, {first_counts[name]} at the "
                                 "first frame; expected the same points at every frame (a piece's points that change "
                                 "in number are no rigid motion)")
            if instance is None:
                M = np.asarray(cache.GetLocalToWorldTransform(p), np.float64)  # row vectors: x' = [x 1] M
            else:  # the mesh in its prototype's space, moved by the instance, in the instancer's world
                instancer, i, root = instance
                if instancer.GetPath() not in placed:
                    placed[instancer.GetPath()] = UsdGeom.PointInstancer(instancer).ComputeInstanceTransformsAtTime(
                        t, t)
                inside = np.asarray(cache.ComputeRelativeTransform(p, root)[0], np.float64)
                M = inside @ np.asarray(placed[instancer.GetPath()][i], np.float64) @ np.asarray(
                    cache.GetLocalToWorldTransform(instancer), np.float64)
            X = P @ M[:3, :3] + M[3, :3]
            if not np.isfinite(X).all():
                raise InputError(f"{path}: piece {name!r} at {when}: NaN or infinite coordinates")
            V.append(X)
            splits = np.split(idx + offset, np.cumsum(counts)[:-1])
            polys.append(splits)
            offset += len(P)
        frames.append(MeshFrame(path, list(names), np.concatenate(V), polys,
                                time=None if t.IsDefault() else float(t.GetValue())))
    if len(names) == 1:  # one mesh holding every piece: its parts
        frames[0] = split_one_object(frames[0])
        frames[1:] = [split_one_object(f, frames[0]) for f in frames[1:]]
    rest = frames[0]
    for t, frame in zip(times[1:], frames[1:]):
        if len(frame.V) != len(rest.V):
            raise InputError(f"{path}: frame {t.GetValue():g} has {len(frame.V)} points, the first has "
                             f"{len(rest.V)}: a piece's points change in number")
    up = "y" if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y else "z"
    fps = float(stage.GetTimeCodesPerSecond())
    if not 0.0 < fps < float("inf"):  # the outputs would play at it
        raise InputError(f"{path}: the stage's timeCodesPerSecond is {fps:g}; expected a positive number of time "
                         "codes per second (24, say)")
    return UsdAnimation(frames, up, fps, float(UsdGeom.GetStageMetersPerUnit(stage)), hidden)


def _at_default_or(attr, time):
    """``attr``'s value at the default time, else at ``time`` (an attribute with time samples only)."""
    value = attr.Get()
    return attr.Get(time) if value is None else value


class _Instanced(NamedTuple):
    """The pieces point instancers make: ``(mesh, (instancer, instance, prototype root))`` per piece, their
    names, every mesh under the instancers' prototypes (not pieces as they are) and the times at which the
    instancers' positions or orientations are sampled."""

    pieces: list
    names: list[str]
    under: list
    times: set


def _instanced(stage, shown) -> _Instanced:
    """The instances of the stage's point instancers as pieces: one per mesh of the prototype an instance
    shows (``shown``: the meshes a renderer shows), named after the prototype (and the instance's number
    where a prototype has several instances)."""
    from pxr import Usd, UsdGeom

    visible = {p.GetPath() for p in shown}
    pieces, names, under, times = [], [], [], set()
    for prim in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies()):
        if not prim.IsA(UsdGeom.PointInstancer):
            continue
        instancer = UsdGeom.PointInstancer(prim)
        roots = [stage.GetPrimAtPath(t) for t in instancer.GetPrototypesRel().GetTargets()]
        inside = [[m for m in Usd.PrimRange(r, Usd.TraverseInstanceProxies()) if m.IsA(UsdGeom.Mesh)]
                  for r in roots if r]
        under += [m for ms in inside for m in ms]
        which = np.asarray(instancer.GetProtoIndicesAttr().Get(Usd.TimeCode.EarliestTime()) or [], np.int64)
        uses = np.bincount(which, minlength=len(roots)) if len(which) else np.zeros(len(roots), np.int64)
        for i, k in enumerate(which.tolist()):
            if not 0 <= k < len(inside):
                continue
            for m in inside[k]:
                if m.GetPath() not in visible:
                    continue
                name = roots[k].GetName() if uses[k] == 1 else f"{roots[k].GetName()}_{i:03d}"
                if len(inside[k]) > 1:
                    name += f"_{m.GetName()}"
                pieces.append((m, (prim, i, roots[k])))
                names.append(name)
        for attr in (instancer.GetPositionsAttr(), instancer.GetOrientationsAttr(), instancer.GetScalesAttr()):
            times.update(attr.GetTimeSamples())
        times.update(UsdGeom.Xformable(prim).GetTimeSamples())
    return _Instanced(pieces, names, under, times)


def _sample_times(meshes) -> list[float]:
    """The times at which the meshes' points or their transforms (theirs or an ancestor's) are sampled."""
    from pxr import UsdGeom

    times, seen = set(), set()
    for p in meshes:
        times.update(UsdGeom.Mesh(p).GetPointsAttr().GetTimeSamples())
        q = p
        while q and not q.IsPseudoRoot() and q.GetPath() not in seen:
            seen.add(q.GetPath())
            if q.IsA(UsdGeom.Xformable):
                times.update(UsdGeom.Xformable(q).GetTimeSamples())
            q = q.GetParent()
    return sorted(times)


def _shown(prim) -> bool:
    """Whether a renderer shows ``prim`` at the stage's first time: visible, and of the default or render
    purpose."""
    from pxr import Usd, UsdGeom

    seen = UsdGeom.Imageable(prim)
    return (seen.ComputeVisibility(Usd.TimeCode.EarliestTime()) != UsdGeom.Tokens.invisible
            and seen.ComputePurpose() in (UsdGeom.Tokens.default_, UsdGeom.Tokens.render))

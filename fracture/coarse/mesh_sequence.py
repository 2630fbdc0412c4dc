"""Per-frame mesh files of a coarse fracture animation (Blender Cell Fracture + rigid bodies).

A sequence is a directory of OBJ (or PLY) files, one per frame, ordered by the
frame number in their names (the last run of digits: ``frame_0001.obj``,
Blender's ``frame1.obj ... frame40.obj``; :func:`frame_paths`); the first is
the rest pose. In an OBJ every piece is an object (``o name``)
and faces may be n-gons; in a PLY, which has no objects, the pieces are the
connected components of the mesh, joined where their open boundaries close
each other (:func:`join_open_shells`), named ``piece_000``, ``piece_001``, ...
in the order of their first vertex; so are those of an OBJ whose one object
holds them all (``NAME_000``, ...: :func:`split_one_object`). Every frame must
have the same pieces, the same vertices in the same order and the same faces.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from fracture.errors import InputError
from fracture.io.meshes import read_obj_objects, read_ply_polygons
from fracture.mesh.topology import diagonal, weld
from fracture.tolerances import tol


@dataclass
class MeshFrame:
    """One frame: vertices and, per piece, its polygons (indices into ``V``).

    Attributes
    ----------
    path : Path
    names : list of str
        Piece names, in file order.
    V : (n, 3) float
    polygons : list of list of (k,) int arrays
        ``polygons[p]`` are the faces of piece ``p``.
    face_piece : (m,) int or None
        For a PLY (which has no objects), or one object holding every piece: each face's piece, in file order.
    time : float or None
        The frame's number in the input (its file's number, a USD time code); None: not known.
    """

    path: Path
    names: list[str]
    V: np.ndarray
    polygons: list[list[np.ndarray]]
    face_piece: np.ndarray | None = None  # PLY: each face's piece, in file order (found once per sequence)
    time: float | None = None

    def piece_vertices(self, p: int) -> np.ndarray:
        """Indices of the vertices used by piece ``p`` (sorted)."""
        return np.unique(np.concatenate(self.polygons[p]))


def _read_ply_pieces(path: Path, face_piece: np.ndarray | None = None) -> MeshFrame:
    """A PLY frame (ASCII or binary, any polygon sizes, as Blender writes it) read with plyfile.

    PLY has no objects: the pieces are the connected components of its faces, joined
    where their open boundaries close each other (:func:`join_open_shells`). Given the
    rest pose's ``face_piece`` (every frame has the same faces), they are taken from it.
    """
    V, polys = read_ply_polygons(path)
    if not polys:
        return MeshFrame(path, [], V.reshape(-1, 3), [])
    if face_piece is None or len(face_piece) != len(polys):
        face_piece = face_pieces(V, polys)
    return MeshFrame(path, [f"piece_{i:03d}" for i in range(face_piece.max() + 1)], V, _grouped(polys, face_piece),
                     face_piece)


def face_pieces(V: np.ndarray, polys: list[np.ndarray]) -> np.ndarray:
    """Each face's piece, when one mesh holds several: the connected components of the faces, joined where
    their open boundaries close each other (:func:`join_open_shells`), numbered in the order of their first
    vertex."""
    n = len(V)
    flat = np.concatenate(polys)
    first = np.repeat(np.array([f[0] for f in polys]), [len(f) for f in polys])
    A = coo_matrix((np.ones(len(flat)), (first, flat)), shape=(n, n))
    _, label = connected_components(A, directed=False)
    # connected_components numbers components by their lowest vertex, which
    # is the "order of the first vertex" rule; keep only labels with faces.
    return np.unique(join_open_shells(V, polys, label[[f[0] for f in polys]]), return_inverse=True)[1]


def _grouped(polys: list[np.ndarray], face_piece: np.ndarray) -> list[list[np.ndarray]]:
    order = np.argsort(face_piece, kind="stable")
    ends = np.cumsum(np.bincount(face_piece))[:-1]
    return [[polys[i] for i in group] for group in np.split(order, ends)]


def split_one_object(frame: MeshFrame, rest: MeshFrame | None = None) -> MeshFrame:
    """A frame whose one object holds all the pieces (an OBJ without objects, a USD of one mesh, as exporters
    write a fracture when asked to merge it) as its pieces (:func:`face_pieces`; ``rest``'s when given: every
    frame has the same faces), named ``NAME_000``, ``NAME_001``, ...; any other frame as it is."""
    if len(frame.names) != 1:
        return frame
    polys = frame.polygons[0]
    face_piece = rest.face_piece if rest is not None and rest.face_piece is not None else None
    if face_piece is None or len(face_piece) != len(polys):
        face_piece = face_pieces(frame.V, polys)
    if face_piece.max() == 0:
        return frame
    names = [f"{frame.names[0]}_{i:03d}" for i in range(face_piece.max() + 1)]
    return MeshFrame(frame.path, names, frame.V, _grouped(polys, face_piece), face_piece, frame.time)


def join_open_shells(V: np.ndarray, polys: list[np.ndarray], face_label: np.ndarray) -> np.ndarray:
    """Join the parts of a piece that a file stores apart: ``face_label`` with merged labels.

    Cell Fracture gives a piece's outer faces and its cut faces vertices of their own, so
    each is an open shell; where several pieces are written to one PLY, only the positions
    say which shells belong together. Two open groups are joined when every boundary edge
    of the smaller one lies (by position) on the other's boundary; among such pairs, the
    one whose union is left with the fewest open edges goes first, so that a piece's outer
    and cut faces pair up before a neighbour's do, then the one whose vertices lie closest
    in the file (an exporter writes a piece's vertices together: two pieces that meet
    along a whole loop, such as the halves of a box cut in two, have four shells that
    pair up either way). Neighbouring pieces touch along part of their boundaries only
    and stay apart.
    """
    _, at = weld(V, tol.same_position * diagonal(V))  # one key per position
    ids = np.concatenate(polys)
    nxt = np.concatenate([np.roll(f, -1) for f in polys])
    labels, owner = np.unique(np.repeat(face_label, [len(f) for f in polys]), return_inverse=True)
    lo = np.full(len(labels), len(V))
    hi = np.full(len(labels), -1)
    np.minimum.at(lo, owner, ids)
    np.maximum.at(hi, owner, ids)
    span = {int(lab): (int(lo[k]), int(hi[k])) for k, lab in enumerate(labels)}
    # open edges of each group: position edges its faces use an odd number of times
    m = len(V)
    key = np.minimum(at[ids], at[nxt]) * m + np.maximum(at[ids], at[nxt])
    pairs, count = np.unique(np.stack([owner, key], 1), axis=0, return_counts=True)
    open_ = pairs[count % 2 == 1]
    boundary: dict[int, set] = {}
    for k, e in open_.tolist():
        boundary.setdefault(int(labels[k]), set()).add(e)
    parent = {}
    while True:
        owners: dict[int, list[int]] = {}
        for g, edges in boundary.items():
            for e in edges:
                owners.setdefault(e, []).append(g)
        shared: dict[tuple[int, int], int] = {}
        for gs in owners.values():
            for i in range(len(gs)):
                for j in range(i + 1, len(gs)):
                    pair = (min(gs[i], gs[j]), max(gs[i], gs[j]))
                    shared[pair] = shared.get(pair, 0) + 1
        best = None
        for (i, j), s in shared.items():
            if s < min(len(boundary[i]), len(boundary[j])):
                continue
            left = len(boundary[i]) + len(boundary[j]) - 2 * s
            gap = max(0, max(span[i][0], span[j][0]) - min(span[i][1], span[j][1]))
            if best is None or (left, gap, i, j) < best:
                best = (left, gap, i, j)
        if best is None:
            break
        *_, i, j = best
        parent[j] = i
        span[i] = (min(span[i][0], span[j][0]), max(span[i][1], span[j][1]))
        rest = boundary[i] ^ boundary.pop(j)
        if rest:
            boundary[i] = rest
        else:
            del boundary[i]
    root = np.arange(face_label.max() + 1)
    for j in parent:
        i = parent[j]
        while i in parent:
            i = parent[i]
        root[j] = i
    return root[face_label]


def read_frame(path: str | Path, rest: MeshFrame | None = None) -> MeshFrame:
    """Read one frame file and check it is not empty and finite (a PLY's pieces as in ``rest``, the
    sequence's first frame, when given)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: frame file not found")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: file is empty")
    suffix = path.suffix.lower()
    if suffix == ".obj":
        frame = split_one_object(MeshFrame(path, *read_obj_objects(path)), rest)
    elif suffix == ".ply":
        frame = _read_ply_pieces(path, rest.face_piece if rest is not None else None)
    else:
        raise InputError(f"{path}: unsupported frame format {path.suffix!r}, expected .obj or .ply")
    if len(frame.V) == 0 or not frame.names:
        raise InputError(f"{path}: no pieces (expected objects with vertices and faces)")
    seen = set()
    for name in frame.names:
        if name in seen:
            raise InputError(f"{path}: two pieces are named {name!r}; expected a distinct name per piece "
                             "(the pieces are matched across frames by name)")
        seen.add(name)
    for p, polys in enumerate(frame.polygons):
        ids = np.concatenate(polys)
        if ids.min() < 0 or ids.max() >= len(frame.V):
            bad = int(ids.max()) if ids.max() >= len(frame.V) else int(ids.min())
            raise InputError(f"{path}: piece {frame.names[p]!r}: a face refers to vertex {bad + 1}, "
                             f"but the file has {len(frame.V)} vertices")
    bad = ~np.isfinite(frame.V).all(axis=1)
    if bad.any():
        v = int(np.flatnonzero(bad)[0])
        owner = next((frame.names[p] for p in range(len(frame.names)) if v in frame.piece_vertices(p)), None)
        where = f"piece {owner!r}, " if owner else ""
        raise InputError(f"{path}: {where}vertex {v + 1} has a NaN or infinite coordinate "
                         f"({int(bad.sum())} such vertices in the file)")
    return frame


# A frame number: a run of digits, negative after a dot or an underscore (Houdini's pre-roll: frac.-3.obj)
_NUMBER = re.compile(r"(?:(?<=[._])-)?\d+")


def frame_number(path: Path) -> int:
    """The frame number in a frame file's name: its last run of digits (``frame_0012.obj``, ``frame12.obj``),
    negative after a dot or an underscore (``frac.-3.obj``; ``cube-0003.obj`` is frame 3)."""
    return int(_NUMBER.findall(path.stem)[-1])


# The suffixes of frame files a sequence may hold (said when the glob finds none).
_MESH_SUFFIXES = (".obj", ".ply")


def frame_paths(directory: Path, pattern: str) -> list[Path]:
    """The frame files of ``directory`` matching ``pattern``, ordered by their frame numbers.

    The frame number is the last run of digits in a file's name (without its
    suffix). Frames must follow at a constant step (Blender may export every
    n-th frame); a file without a number, two files of one frame, or a gap in
    the numbers is an error naming the files.
    """
    paths = [p for p in directory.glob(pattern) if p.is_file()]
    if not paths:
        # the suffixes as the files spell them ('.OBJ' is not matched by '*.obj')
        others = sorted({p.suffix for p in directory.iterdir() if p.is_file() and p.suffix.lower() in _MESH_SUFFIXES})
        hint = "".join(f"; it holds {s} files: set input.glob: '*{s}'" for s in others[:1])
        raise InputError(f"{directory}: no frame files match {pattern!r}{hint}")
    numbered = []
    for p in paths:
        digits = re.findall(r"\d+", p.stem)
        if not digits:
            raise InputError(f"{p}: no frame number in the file name (expected e.g. frame_0001{p.suffix} or "
                             f"frame1{p.suffix}, as Blender writes them)")
        numbered.append((frame_number(p), p.name, p))
    numbered.sort()
    numbers = [n for n, _, _ in numbered]
    for (a, na, _), (b, nb, _) in zip(numbered, numbered[1:]):
        if a == b:
            raise InputError(f"{directory}: {na} and {nb} are both frame {a}")
    if len(numbers) > 2:
        step = min(b - a for a, b in zip(numbers, numbers[1:]))
        for (a, na, _), (b, nb, _) in zip(numbered, numbered[1:]):
            if b - a == step:
                continue
            if (b - a) % step:
                raise InputError(f"{directory}: frames do not follow at a constant step: {na} (frame {a}) then "
                                 f"{nb} (frame {b}), elsewhere every {step}")
            gone = range(a + step, b, step)
            which = (f"frame {', '.join(map(str, gone))} missing" if len(gone) <= 5 else
                     f"frames {gone[0]} to {gone[-1]} missing ({len(gone):,} frames"
                     f"{'' if step == 1 else f', every {step}'})")
            raise InputError(f"{directory}: {which} between {na} and {nb}")
    return [p for _, _, p in numbered]


def read_sequence(directory: str | Path, pattern: str = "*.obj") -> list[MeshFrame]:
    """Read and cross-check all frames of a sequence.

    Raises
    ------
    InputError
        Naming the file (and frame number, 1-based) and the piece, when the
        directory has no frames or frames differ in pieces, vertex counts or
        faces.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError(f"{directory}: mesh sequence directory not found")
    paths = frame_paths(directory, pattern)
    frames = [read_frame(paths[0])]
    rest = frames[0]
    rest.time = float(frame_number(paths[0]))
    for number, path in enumerate(paths[1:], 2):
        frame = read_frame(path, rest)
        frame.time = float(frame_number(path))
        where = f"{path} (frame {number})"
        missing = [n for n in rest.names if n not in frame.names]
        extra = [n for n in frame.names if n not in rest.names]
        if missing:
            raise InputError(f"{where}: piece {missing[0]!r} of the rest pose ({rest.path.name}) is missing")
        if extra:
            raise InputError(f"{where}: piece {extra[0]!r} is not in the rest pose ({rest.path.name})")
        if frame.names != rest.names:  # the same pieces, written in another order: matched by name
            frame = _in_rest_order(frame, rest, where)
        if len(frame.V) != len(rest.V):
            raise _vertex_counts_differ(frame, rest, where)
        for p, name in enumerate(rest.names):
            a, b = rest.polygons[p], frame.polygons[p]
            if (len(a) != len(b) or not np.array_equal([len(x) for x in a], [len(y) for y in b])
                    or not np.array_equal(np.concatenate(a), np.concatenate(b))):
                raise InputError(f"{where}: piece {name!r} has different faces than in the rest pose ({rest.path.name})")
        frames.append(frame)
    return frames


def _vertex_counts_differ(frame: MeshFrame, rest: MeshFrame, where: str) -> InputError:
    """The error of a frame whose vertex count is not the rest pose's (the same pieces): the first piece, by
    name, whose own count differs, else the vertices that no piece uses."""
    for name in rest.names:
        mine, theirs = (len(f.piece_vertices(f.names.index(name))) for f in (frame, rest))
        if mine != theirs:
            return InputError(f"{where}: piece {name!r} has {mine} vertices, but {theirs} in the rest pose "
                              f"({rest.path.name})")
    return InputError(f"{where}: {len(frame.V)} vertices, but the rest pose ({rest.path.name}) has {len(rest.V)} "
                      "(the difference in vertices no piece uses)")


def _in_rest_order(frame: MeshFrame, rest: MeshFrame, where: str) -> MeshFrame:
    """``frame``, whose pieces are those of ``rest`` in another order, with its pieces and vertices put in
    ``rest``'s order: each piece's vertices (ascending) take the places of the rest pose's vertices of the
    piece of that name (ascending), the vertices no piece uses the places left, in order."""
    where_in = {name: p for p, name in enumerate(frame.names)}
    if len(frame.V) != len(rest.V):
        raise _vertex_counts_differ(frame, rest, where)
    to_rest = np.full(len(frame.V), -1, np.int64)
    polygons = []
    for p, name in enumerate(rest.names):
        q = where_in[name]
        mine, theirs = frame.piece_vertices(q), rest.piece_vertices(p)
        if len(mine) != len(theirs) or (to_rest[mine] >= 0).any():
            raise InputError(f"{where}: piece {name!r} has {len(mine)} vertices, but {len(theirs)} in the rest pose "
                             f"({rest.path.name})" if len(mine) != len(theirs) else
                             f"{where}: piece {name!r} shares vertices with another piece (expected its own)")
        to_rest[mine] = theirs
        polygons.append([to_rest[f] for f in frame.polygons[q]])
    free = np.setdiff1d(np.arange(len(rest.V)), to_rest[to_rest >= 0])
    to_rest[to_rest < 0] = free
    V = np.empty_like(frame.V)
    V[to_rest] = frame.V
    return MeshFrame(frame.path, list(rest.names), V, polygons, frame.face_piece, frame.time)


def _compact(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    used, inverse = np.unique(F, return_inverse=True)
    return V[used], inverse.reshape(F.shape)


def coordinate_quantum(V: np.ndarray) -> float:
    """The step the coordinates ``V`` were rounded to as they were written: ``10^-d`` for the fewest decimals
    ``d`` (up to 9) that write them all (a text file's ``%.6f``), at least the spacing of single-precision
    numbers at their largest magnitude when they are all such numbers (a binary PLY, USD's points); 0 when
    they are neither (exact doubles)."""
    V = np.asarray(V, np.float64).ravel()
    if not len(V):
        return 0.0
    single = bool(np.array_equal(V, V.astype(np.float32)))
    spacing = float(np.spacing(np.float32(np.abs(V).max()))) if single else 0.0
    for d in range(10):  # a written decimal read back carries the double's (or the single's) own error only
        step = 10.0 ** -d
        if step <= 2.0 * spacing:
            break
        scaled = V / step
        if np.abs(scaled - np.rint(scaled)).max() <= tol.decimal + spacing / step:
            return step
    return spacing


def up_axis_of(frames: list[MeshFrame], vids: np.ndarray | None = None) -> str | None:
    """The up axis of an animation of falling pieces (their vertices ``vids``, default all): the axis along
    which their centroids moved most, provided they moved down it by more than 1 % of the object's size;
    None when they did not."""
    first, last = (frames[0].V, frames[-1].V) if vids is None else (frames[0].V[vids], frames[-1].V[vids])
    d = (last - first).mean(axis=0)
    size = diagonal(first)
    k = int(np.argmax(np.abs(d)))
    if d[k] >= -0.01 * size:
        return None
    return "xyz"[k]


def load_coarse_sequence(directory: str | Path, pattern: str = "*.obj", lattice: int = 2,
                         separation: float = 1e-3, up_axis: str = "auto"):
    """Import a per-frame mesh sequence as a :class:`~fracture.coarse.surface.CoarseFracture`
    (:func:`read_sequence`, then :func:`coarse_from_frames`).

    Parameters
    ----------
    directory : str or Path
        Folder of frame files; the first (by number) is the rest pose.
    pattern : str
        Glob selecting the frame files.
    lattice, separation, up_axis
        As for :func:`coarse_from_frames`.
    """
    return coarse_from_frames(read_sequence(directory, pattern), lattice, separation, up_axis)


def coarse_from_frames(frames: list[MeshFrame], lattice: int = 2, separation: float = 1e-3,
                       up_axis: str = "auto"):
    """A :class:`~fracture.coarse.surface.CoarseFracture` from the frames of an animation of pieces.

    Parameters
    ----------
    frames : list of MeshFrame
        The first is the rest pose; every frame has the same pieces and faces.
    lattice : int
        Nodes per axis of the lattice fitted to a piece that does not move
        rigidly (2: trilinear, which includes every affine map).
    separation : float
        Two sides of a fracture location have separated once they are this
        far apart, relative to the object's box diagonal.
    up_axis : str
        "x", "y" or "z", or "auto": the axis the pieces fall down (:func:`up_axis_of`), else "z".
    """
    from fracture.coarse.animation import CoarseAnimation, fit_lattice, lattice_box
    from fracture.coarse.surface import make_coarse
    from fracture.coarse.tiling import label_tiling

    rest = frames[0]
    shared = label_tiling(rest.V, rest.polygons, rest.names, source=str(rest.path))
    names = [rest.names[p] for p in shared.kept]
    piece_vids = [rest.piece_vertices(p) for p in shared.kept]
    object_vids = np.concatenate(piece_vids)
    diag = diagonal(rest.V[object_vids])
    V, F = _compact(shared.V, shared.fracture_F)
    BV, BF = _compact(shared.V, shared.exterior_F)

    n_pieces, n_frames = len(names), len(frames)
    lo, hi = np.empty((n_pieces, 3)), np.empty((n_pieces, 3))
    nodes = np.empty((n_frames, n_pieces, lattice, lattice, lattice, 3))
    residual = np.zeros((n_pieces, n_frames))
    rigid = np.zeros((n_pieces, n_frames))
    # a rigid motion of points the file rounded is rigid to within the rounding: each coordinate of the rest
    # pose and of the frame off by half a step, a point by sqrt(3) / 2 of it, the fit's largest error by twice
    # that (a small object written with 6 decimals: every piece was fitted with a lattice)
    quantum = max(coordinate_quantum(frame.V) for frame in frames)
    rigid_tolerance = max(tol.rigid_fit * diag, np.sqrt(3.0) * quantum)
    for p, vids in enumerate(piece_vids):
        X = rest.V[vids]
        lo[p], hi[p] = lattice_box(X)
        for t, frame in enumerate(frames):
            nodes[t, p], residual[p, t], rigid[p, t] = fit_lattice(
                X, frame.V[vids], lo[p], hi[p], lattice, rigid_tolerance=rigid_tolerance)
    animation = CoarseAnimation(lo, hi, nodes)
    notes = list(shared.notes)
    deforming = np.flatnonzero(rigid.max(axis=1) > rigid_tolerance)
    if len(deforming):
        notes.append(f"pieces that do not move rigidly, fitted with a {lattice}^3 lattice: "
                     + ", ".join(names[p] for p in deforming))
    if up_axis == "auto":
        found = up_axis_of(frames, object_vids)
        if found is None:
            notes.append("the pieces do not fall: the up axis is taken to be z")
        up_axis = found or "z"
    cf = make_coarse(BV, BF, shared.exterior_piece, V, F, shared.sides, names, animation, separation,
                     fit_residual=residual, notes=notes)
    cf.up_axis = up_axis
    cf.source = replace(cf.source, **_numbering(frames))
    return cf, {"rigid_residual": rigid, "tiling_cells": shared.cells}


def _numbering(frames: list[MeshFrame]) -> dict:
    """The input's number of its first frame and the step between its frames (both 1 when it did not say)."""
    if frames[0].time is None:
        return {}
    step = frames[1].time - frames[0].time if len(frames) > 1 and frames[1].time is not None else 1.0
    return {"first_frame": float(frames[0].time), "frame_step": float(step)}

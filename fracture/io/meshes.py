"""Reading and checking triangle meshes at the door."""

from __future__ import annotations

from pathlib import Path

import igl
import numpy as np

from fracture.errors import InputError
from fracture.mesh.clean import flat_triangles
from fracture.mesh.topology import fan, unique_edges

MESH_SUFFIXES = (".obj", ".ply", ".off", ".stl")


def check_triangle_mesh(V, F, what: str, closed: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Validate a triangle mesh and return it as ``float64`` / ``int64`` arrays.

    Parameters
    ----------
    V : (n, 3) array_like of float
    F : (m, 3) array_like of int
    what : str
        Names the mesh in error messages (file, config key, piece).
    closed : bool
        Also require every edge to have exactly two incident triangles
        (a closed, edge-manifold surface). Triangles without area are
        refused only when not ``closed``.

    Raises
    ------
    InputError
        With expected versus actual.
    """
    V = np.asarray(V)
    F = np.asarray(F)
    if V.size == 0 or F.size == 0:  # a file of another kind read as a mesh, or one with no surface in it
        raise InputError(f"{what}: no {'vertices' if V.size == 0 else 'faces'} found; expected a triangle mesh "
                         "(is it a mesh file of this format?)")
    if V.ndim != 2 or V.shape[1] != 3:
        raise InputError(f"{what}: vertices have shape {V.shape}, expected (n, 3) with n > 0")
    if F.ndim != 2 or F.shape[1] != 3:
        raise InputError(f"{what}: faces have shape {F.shape}, expected (m, 3) triangles with m > 0")
    if not np.issubdtype(V.dtype, np.number) or not np.issubdtype(F.dtype, np.integer):
        raise InputError(f"{what}: expected float vertices and integer faces, got {V.dtype} and {F.dtype}")
    V = np.ascontiguousarray(V, np.float64)
    F = np.ascontiguousarray(F, np.int64)
    bad = ~np.isfinite(V).all(axis=1)
    if bad.any():
        raise InputError(f"{what}: {int(bad.sum())} vertices have NaN or infinite coordinates (first: vertex "
                         f"{int(np.flatnonzero(bad)[0]) + 1}, counted from 1)")
    outside = np.flatnonzero(((F < 0) | (F >= len(V))).any(axis=1))
    if len(outside):
        f = int(outside[0])
        corner = int(F[f][(F[f] < 0) | (F[f] >= len(V))][0])
        raise InputError(f"{what}: face {f + 1} refers to vertex {corner + 1} (both counted from 1), but there are "
                         f"{len(V)} vertices{f' ({len(outside)} such faces)' if len(outside) > 1 else ''}; expected "
                         f"vertex numbers 1 to {len(V)}")
    repeated = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2])
    if repeated.any():
        raise InputError(f"{what}: {int(repeated.sum())} faces repeat a vertex (first: face "
                         f"{int(np.flatnonzero(repeated)[0]) + 1}, counted from 1); expected three distinct corners")
    _, first, inverse = np.unique(np.sort(F, axis=1), axis=0, return_index=True, return_inverse=True)
    twice = np.flatnonzero(first[inverse.ravel()] != np.arange(len(F)))
    if len(twice):
        f = int(twice[0])
        raise InputError(f"{what}: faces {int(first[inverse.ravel()[f]]) + 1} and {f + 1} (counted from 1) are the same "
                         f"triangle{f' ({len(twice)} such repeats)' if len(twice) > 1 else ''}; expected each triangle once")
    flat = np.flatnonzero(flat_triangles(V, F))
    # only an open surface (a fracture surface) is refused for them: a closed exterior made by CAD
    # booleans often keeps flat triangles where coplanar faces merged, and they bound nothing
    if len(flat) and not closed:
        raise InputError(f"{what}: face {int(flat[0]) + 1} (counted from 1) has no area: its corners coincide or lie on "
                         f"a line{f' ({len(flat)} such faces)' if len(flat) > 1 else ''}; expected triangles with area")
    if closed:
        _, counts = unique_edges(F)
        if np.any(counts != 2):
            open_edges = int((counts == 1).sum())
            nonmanifold = int((counts > 2).sum())
            twins = len(V) - len(np.unique(V, axis=0))
            hint = (f"; {twins} vertices lie exactly where others do: the faces are not joined there (merge them, "
                    "with Merge by Distance in Blender, say)" if twins and open_edges else "")
            raise InputError(
                f"{what}: expected a closed surface (every edge shared by exactly 2 triangles), "
                f"found {open_edges} boundary edges and {nonmanifold} edges shared by more than 2 triangles{hint}"
            )
    return V, F


def read_mesh(path: str | Path, what: str | None = None, closed: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle mesh (OBJ, PLY, OFF, STL; polygons are fan-triangulated).

    STL stores every triangle's corners apart: corners at the same position
    are merged into one vertex, so that a closed surface reads as closed.

    Parameters
    ----------
    path : str or Path
    what : str, optional
        Prefix for error messages (default: the path).
    closed : bool
        See :func:`check_triangle_mesh`.
    """
    path = Path(path)
    what = f"{what} ({path})" if what else str(path)
    if not path.is_file():
        raise InputError(f"{what}: mesh file not found")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise InputError(f"{what}: unsupported mesh format {path.suffix!r}, expected one of {', '.join(MESH_SUFFIXES)}")
    if path.stat().st_size == 0:
        raise InputError(f"{what}: file is empty")
    suffix = path.suffix.lower()
    if suffix == ".obj":
        V, F = read_obj(path, what)
    elif suffix == ".ply":
        V, polys = read_ply_polygons(path, what)
        F = fan(polys, V)[0]
    else:
        try:
            V, F = igl.read_triangle_mesh(str(path))
        except Exception as exc:  # libigl raises RuntimeError with little detail
            raise InputError(f"{what}: cannot read this {suffix[1:].upper()} file (libigl: {exc})") from None
        if suffix == ".stl" and len(V):
            V, inverse = np.unique(np.asarray(V), axis=0, return_inverse=True)
            F = inverse.reshape(-1)[np.asarray(F)]
    return check_triangle_mesh(V, F, what, closed=closed)


def read_ply_polygons(path: Path, what: str | None = None) -> tuple[np.ndarray, list[np.ndarray]]:
    """Vertices and polygons (any sizes, as Blender writes them) of an ASCII or binary PLY file.

    Read with plyfile: libigl's PLY reader aborts the interpreter on lists of
    mixed lengths.
    """
    from plyfile import PlyData, PlyParseError

    what = what or str(path)
    try:
        ply = PlyData.read(str(path))
        if "vertex" not in ply:
            raise InputError(f"{what}: no vertex element; expected a PLY mesh with vertices and faces")
        vert = ply["vertex"]
        missing = [c for c in ("x", "y", "z") if c not in vert.data.dtype.names]
        if missing:
            raise InputError(f"{what}: the vertices have no {', '.join(missing)} property")
        V = np.stack([np.asarray(vert[c], np.float64) for c in ("x", "y", "z")], 1)
        face = ply["face"] if "face" in ply else None
        names = face.data.dtype.names if face is not None else ()
        key = next((k for k in ("vertex_indices", "vertex_index") if k in names), None)
        if face is not None and key is None:
            raise InputError(f"{what}: the face element has no vertex_indices list")
        polys = [np.asarray(f, np.int64) for f in face[key]] if face is not None else []
    except InputError:
        raise
    except (PlyParseError, KeyError, ValueError, IndexError, TypeError, OSError) as exc:
        raise InputError(f"{what}: cannot read PLY ({exc})") from None
    for i, f in enumerate(polys):
        if len(f) < 3 or f.min() < 0 or f.max() >= len(V):
            raise InputError(f"{what}: face {i + 1} (counted from 1) has {len(f)} corners or a corner outside the "
                             f"{len(V)} vertices; expected 3 or more corners among them")
    return V.reshape(-1, 3), polys


def read_obj_objects(path: Path, what: str | None = None) -> tuple[list[str], np.ndarray, list[list[np.ndarray]]]:
    """Objects of a Wavefront OBJ file: names, all vertices, and per object its polygons.

    Our own reader rather than libigl's, so that errors can name the line,
    objects (``o``/``g``) are kept apart, and non-finite coordinates reach the
    checks (libigl rejects them with a message on stderr only). Accepts
    ``v/vt/vn`` face tokens and negative (relative) indices; ignores other
    records. Objects without faces are dropped; faces before any ``o`` line
    belong to ``object_000``.
    """
    what = what or str(path)
    verts: list[list[float]] = []
    names: list[str] = []
    polys: list[list[np.ndarray]] = []
    with open(path, encoding="utf-8-sig", errors="replace") as f:
        for lineno, line in enumerate(f, 1):
            parts = line.split()
            if not parts:
                continue
            try:
                if parts[0] in ("o", "g"):
                    if parts[0] == "g" and names and not polys[-1]:
                        continue  # a group name right after an object name
                    names.append(" ".join(parts[1:]) or f"object_{len(names):03d}")
                    polys.append([])
                elif parts[0] == "v":
                    xyz = [float(x) for x in parts[1:4]]
                    if len(xyz) != 3:
                        raise ValueError("a vertex needs 3 coordinates")
                    verts.append(xyz)
                elif parts[0] == "f":
                    idx = [int(tok.split("/")[0]) for tok in parts[1:]]
                    if len(idx) < 3:
                        raise ValueError("a face needs at least 3 vertices")
                    if 0 in idx:
                        raise ValueError("a face uses vertex 0; OBJ counts its vertices from 1 (or back from -1)")
                    if not names:
                        names.append("object_000")
                        polys.append([])
                    polys[-1].append(np.array([i - 1 if i > 0 else len(verts) + i for i in idx], np.int64))
            except ValueError as exc:
                raise InputError(f"{what}: line {lineno}: {exc}: {line.strip()[:80]!r}") from None
    keep = [i for i, p in enumerate(polys) if p]
    return [names[i] for i in keep], np.array(verts, np.float64).reshape(-1, 3), [polys[i] for i in keep]


def read_obj(path: Path, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and fan-triangulated faces of all objects of an OBJ file."""
    _, V, polys = read_obj_objects(path, what)
    return V, fan([f for obj in polys for f in obj], V)[0]

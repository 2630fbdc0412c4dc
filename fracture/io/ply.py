"""Binary PLY files with extra per-vertex and per-face properties, through plyfile.

Open3D and pymeshlab drop custom face properties (the component ids on the two
sides of a fracture triangle); plyfile keeps them. Output is deterministic:
the same arrays give the same bytes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement, PlyParseError

from fracture.errors import InputError


def _column(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a)
    return a.astype(np.int32) if a.dtype == np.int64 else a


def write_ply(path: str | Path, V: np.ndarray, F: np.ndarray, vertex_data: dict | None = None,
              face_data: dict | None = None) -> None:
    """Write a little-endian binary PLY.

    Parameters
    ----------
    V : (n, 3) float
    F : (m, 3) int
    vertex_data, face_data : dict of name -> (n,) or (m,) arrays
        Extra scalar properties (float32, float64, int32/int64, uint8).
    """
    vertex_data = {k: _column(v) for k, v in (vertex_data or {}).items()}
    face_data = {k: _column(v) for k, v in (face_data or {}).items()}
    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int32)
    vrec = np.empty(len(V), [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
                    + [(k, a.dtype.newbyteorder("<")) for k, a in vertex_data.items()])
    for c, name in enumerate("xyz"):
        vrec[name] = V[:, c]
    for k, a in vertex_data.items():
        vrec[k] = a
    frec = np.empty(len(F), [("vertex_indices", "<i4", (3,))] + [(k, a.dtype.newbyteorder("<")) for k, a in face_data.items()])
    frec["vertex_indices"] = F
    for k, a in face_data.items():
        frec[k] = a
    faces = PlyElement.describe(frec, "face", len_types={"vertex_indices": "u1"}, val_types={"vertex_indices": "i4"})
    ply = PlyData([PlyElement.describe(vrec, "vertex"), faces], text=False, byte_order="<")
    # plyfile writes list properties row by row (a tenth of a second per 20K triangles); every face
    # list here has three entries, so the face rows are one packed record array, written at once
    packed = np.empty(len(F), [("n", "u1"), ("vertex_indices", "<i4", (3,))]
                      + [(k, a.dtype.newbyteorder("<")) for k, a in face_data.items()])
    packed["n"] = 3
    for k in frec.dtype.names:
        packed[k] = frec[k]
    with open(path, "wb") as f:
        f.write(ply.header.encode("ascii") + b"\n")
        f.write(vrec.tobytes())
        f.write(packed.tobytes())


def read_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray, dict, dict]:
    """Read a triangle PLY with scalar properties (as :func:`write_ply` writes it).

    Returns
    -------
    V, F, vertex_data, face_data
    """
    path = Path(path)
    try:  # triangles: the face lists are read as one (m, 3) array, not m small ones
        ply = PlyData.read(str(path), known_list_len={"face": {"vertex_indices": 3}})
        names = [e.name for e in ply.elements]
        if "vertex" not in names:
            raise InputError(f"{path}: no vertex element")
        v = ply["vertex"].data
        f = ply["face"].data if "face" in names else None
        F = np.array(f["vertex_indices"], np.int64).reshape(-1, 3) if f is not None else np.zeros((0, 3), np.int64)
    except (PlyParseError, ValueError, OSError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"{path}: not a readable PLY file of triangles ({exc})") from None
    V = np.stack([v["x"], v["y"], v["z"]], 1).astype(np.float64)
    vdata = {k: np.array(v[k]) for k in v.dtype.names if k not in ("x", "y", "z")}
    fdata = {k: np.array(f[k]) for k in f.dtype.names if k != "vertex_indices"} if f is not None else {}
    return V, F, vdata, fdata

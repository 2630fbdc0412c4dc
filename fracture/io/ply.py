"""Binary PLY files with extra per-vertex and per-face properties.

Open3D and pymeshlab drop custom face properties (the component ids on the two
sides of a fracture triangle), so this small writer/reader covers them. Output
is deterministic: the same arrays give the same bytes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fracture.errors import InputError

_PLY_TYPES = {np.dtype("float32"): "float", np.dtype("float64"): "double", np.dtype("int32"): "int",
              np.dtype("uint8"): "uchar", np.dtype("int64"): "int"}


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
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {len(V)}",
            "property double x", "property double y", "property double z"]
    head += [f"property {_PLY_TYPES[a.dtype]} {k}" for k, a in vertex_data.items()]
    head += [f"element face {len(F)}", "property list uchar int vertex_indices"]
    head += [f"property {_PLY_TYPES[a.dtype]} {k}" for k, a in face_data.items()]
    head.append("end_header")
    vdt = np.dtype([("p", "<f8", 3)] + [(k, a.dtype.newbyteorder("<")) for k, a in vertex_data.items()])
    fdt = np.dtype([("n", "u1"), ("f", "<i4", 3)] + [(k, a.dtype.newbyteorder("<")) for k, a in face_data.items()])
    vrec = np.empty(len(V), vdt)
    vrec["p"] = V
    for k, a in vertex_data.items():
        vrec[k] = a
    frec = np.empty(len(F), fdt)
    frec["n"] = 3
    frec["f"] = F
    for k, a in face_data.items():
        frec[k] = a
    with open(path, "wb") as f:
        f.write(("\n".join(head) + "\n").encode("ascii"))
        f.write(vrec.tobytes())
        f.write(frec.tobytes())


_NP_TYPES = {"float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8", "int": "<i4", "int32": "<i4",
             "uint": "<u4", "uchar": "u1", "uint8": "u1", "char": "i1", "short": "<i2", "ushort": "<u2"}


def read_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray, dict, dict]:
    """Read a binary PLY written by :func:`write_ply` (triangles, scalar properties).

    Returns
    -------
    V, F, vertex_data, face_data
    """
    path = Path(path)
    with open(path, "rb") as f:
        data = f.read()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply") or end < 0:
        raise InputError(f"{path}: not a PLY file")
    header = data[:end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in header:
        raise InputError(f"{path}: only binary little-endian PLY is supported here")
    elements, current = [], None
    for line in header:
        parts = line.split()
        if parts[0] == "element":
            current = (parts[1], int(parts[2]), [])
            elements.append(current)
        elif parts[0] == "property" and current is not None:
            if parts[1] == "list":
                if parts[2] != "uchar" or parts[3] not in ("int", "int32", "uint"):
                    raise InputError(f"{path}: unsupported list property {line!r}")
                current[2].append(("__list__", parts[4]))
            else:
                current[2].append((parts[2], _NP_TYPES[parts[1]]))
    offset = end + len(b"end_header\n")
    out = {}
    for name, count, props in elements:
        fields = []
        for pname, ptype in props:
            fields += [("n", "u1"), ("f", "<i4", 3)] if pname == "__list__" else [(pname, ptype)]
        dt = np.dtype(fields)
        rec = np.frombuffer(data, dt, count, offset)
        offset += dt.itemsize * count
        out[name] = rec
    v, f = out["vertex"], out.get("face")
    V = np.stack([v["x"], v["y"], v["z"]], 1).astype(np.float64)
    vdata = {k: np.array(v[k]) for k in v.dtype.names if k not in ("x", "y", "z")}
    if f is None:
        return V, np.zeros((0, 3), np.int64), vdata, {}
    if np.any(f["n"] != 3):
        raise InputError(f"{path}: only triangle faces are supported here")
    fdata = {k: np.array(f[k]) for k in f.dtype.names if k not in ("n", "f")}
    return V, np.array(f["f"], np.int64), vdata, fdata

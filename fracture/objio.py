"""Wavefront OBJ output: one file per frame, one object (``o name``) per piece, as Blender imports it."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def face_block(F: np.ndarray, offset: int) -> str:
    """The ``f`` lines of triangles ``F`` whose vertices start at 1-based index ``offset + 1``."""
    F = np.asarray(F, np.int64) + offset + 1
    return ("f %d %d %d\n" * len(F)) % tuple(F.ravel())


def vertex_block(V: np.ndarray) -> str:
    return ("v %.6f %.6f %.6f\n" * len(V)) % tuple(np.asarray(V, np.float64).ravel())


class ObjFrames:
    """Writes frames of fixed-topology objects; the face lines are formatted once.

    Parameters
    ----------
    names : list of str
        Object names (Blender's object names on import).
    faces : list of (m_i, 3) int
        Triangles of each object, indexing that object's own vertices.
    sizes : list of int
        Vertex count of each object.
    """

    def __init__(self, names: list[str], faces: list[np.ndarray], sizes: list[int]):
        if not (len(names) == len(faces) == len(sizes)):
            raise ValueError("one name, face array and vertex count per object")
        self.names = [str(n).replace("\n", " ") for n in names]
        offsets = np.r_[0, np.cumsum(sizes)[:-1]]
        self.faces = [face_block(F, int(o)) for F, o in zip(faces, offsets)]
        self.sizes = list(sizes)

    def write(self, path: str | Path, positions: list[np.ndarray], header: str = "") -> None:
        """Write one frame: ``positions[i]`` are object ``i``'s vertices."""
        parts = [f"# {header}\n" if header else ""]
        for name, V, fb, n in zip(self.names, positions, self.faces, self.sizes):
            if len(V) != n:
                raise ValueError(f"object {name!r}: {len(V)} positions for {n} vertices")
            parts += [f"o {name}\n", vertex_block(V), "s off\n", fb]
        Path(path).write_text("".join(parts), encoding="ascii")

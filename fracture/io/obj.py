"""Wavefront OBJ output: one file per frame, one object (``o name``) per piece, as Blender imports it."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def write_obj(path, V: np.ndarray, F: np.ndarray) -> None:
    """A plain OBJ file of one mesh (vertices with 6 decimals, 1-based triangles), written atomically."""
    from fracture.io.atomic import atomic_write_text

    atomic_write_text(path, vertex_block(V) + face_block(F, 0))


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
    exterior : list of (m_i,) bool, optional
        Which triangles lie on the object's surface: the faces are then written
        in two groups, ``usemtl exterior`` and ``usemtl interior`` (the fracture
        faces), with ``mtllib`` naming ``materials`` (written by :meth:`write_materials`).
    materials : str
        File name of the material library.
    """

    def __init__(self, names: list[str], faces: list[np.ndarray], sizes: list[int],
                 exterior: list[np.ndarray] | None = None, materials: str = "materials.mtl"):
        if not (len(names) == len(faces) == len(sizes)):
            raise ValueError("one name, face array and vertex count per object")
        self.names = [str(n).replace("\n", " ") for n in names]
        offsets = np.r_[0, np.cumsum(sizes)[:-1]]
        self.materials = materials if exterior is not None else None
        if exterior is None:
            self.faces = [face_block(F, int(o)) for F, o in zip(faces, offsets)]
        else:
            self.faces = ["".join(f"usemtl {kind}\n" + face_block(F[which], int(o))
                                  for kind, which in (("exterior", np.asarray(e, bool)), ("interior", ~np.asarray(e, bool)))
                                  if which.any())
                          for F, e, o in zip(faces, exterior, offsets)]
        self.sizes = list(sizes)

    def write_materials(self, path: str | Path) -> None:
        """The material library the frames name (``path`` ends in :attr:`materials`): ``exterior`` (stone
        grey) and ``interior`` (the break)."""
        if self.materials is not None:
            Path(path).write_text(
                "newmtl exterior\nKd 0.62 0.62 0.60\n\nnewmtl interior\nKd 0.55 0.35 0.25\n", encoding="ascii")

    def write(self, path: str | Path, positions: list[np.ndarray], header: str = "") -> None:
        """Write one frame: ``positions[i]`` are object ``i``'s vertices."""
        parts = [f"# {header}\n" if header else ""]
        if self.materials is not None:
            parts.append(f"mtllib {self.materials}\n")
        for name, V, fb, n in zip(self.names, positions, self.faces, self.sizes):
            if len(V) != n:
                raise ValueError(f"object {name!r}: {len(V)} positions for {n} vertices")
            parts += [f"o {name}\n", vertex_block(V), "s off\n", fb]
        Path(path).write_text("".join(parts), encoding="ascii")

"""Arrays a user gives in NumPy's ``.npy`` files (strength volumes, fibre directions)."""

from __future__ import annotations

from pathlib import Path

# The first bytes of every .npy file (NumPy's format, version 1 to 3).
_MAGIC = b"\x93NUMPY"


def is_npy(path: str | Path) -> bool:
    """Whether the file starts as NumPy's ``.npy`` format does: told before :func:`numpy.load`, which says of an
    OBJ or a text file that it "contains pickled (object) data"."""
    with open(path, "rb") as f:
        return f.read(len(_MAGIC)) == _MAGIC

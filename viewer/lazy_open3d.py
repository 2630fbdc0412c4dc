"""Open3D's machine-learning package loaded on first use rather than with Open3D.

``import open3d`` imports Open3D-ML (``open3d.ml``: its datasets import
scikit-learn and SciPy's statistics), 1.9 s of the 3.3 s the import takes on
the project's 2-core machine; the viewer uses none of it. The command line's
``view``, ``render`` and the sweep's contact sheet (programs of their own)
call :func:`defer_open3d_ml` before they import the viewer: ``open3d.ml`` is then a module that Python's
:class:`importlib.util.LazyLoader` executes at its first attribute access,
so code that does use it still gets all of it. Importing the viewer as a
library changes nothing.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import importlib.util
import sys

_NAME = "open3d.ml"


class _LazyFinder(importlib.abc.MetaPathFinder):
    """Finds ``open3d.ml`` with the usual finders and wraps its loader in a LazyLoader (once)."""

    def find_spec(self, name, path, target=None):
        if name != _NAME:
            return None
        sys.meta_path.remove(self)  # the real search below, and no later one
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is None or spec.loader is None:
            return spec
        spec.loader = importlib.util.LazyLoader(spec.loader)
        return spec


def defer_open3d_ml() -> bool:
    """Make the coming import of Open3D load ``open3d.ml`` lazily (module notes). Returns False, changing
    nothing, when Open3D is imported already."""
    if "open3d" in sys.modules:
        return False
    if not any(isinstance(f, _LazyFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _LazyFinder())
    return True

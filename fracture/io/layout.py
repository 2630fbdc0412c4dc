"""The run directory's layout: every file a run writes, named once.

The stages write these files (``ctx.path(layout.TREE)``), and the viewer,
``fracref export``, the fidelity figures, sweeps and the benchmarks read
them, through the names here and the loaders below. Paths are relative to
the run directory, with ``/`` as the separator.

``manifest.json`` is written last: a directory with one is a complete run
(:mod:`fracture.pipeline.runner`).
"""

from __future__ import annotations

import json
import zipfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import yaml

from fracture.errors import InputError

MANIFEST = "manifest.json"
CONFIG = "config.yaml"

# fields stage
GRID = "fields/grid.json"
PYRAMID = "fields/pyramid.npy"
PREVIEW = "fields/preview.png"

# coarse stage
EXTERIOR = "coarse/exterior.ply"
COARSE_SURFACE = "coarse/fracture_surface.ply"
COMPONENTS = "coarse/components.json"
ANIMATION_LO = "coarse/animation_lo.npy"
ANIMATION_HI = "coarse/animation_hi.npy"
ANIMATION_NODES = "coarse/animation_nodes.npy"
FIT_RESIDUAL = "coarse/fit_residual.npy"

# refine stage
REFINED_SURFACE = "refined/fracture_surface.ply"
TREE = "refined/tree.npz"
ITERATIONS = "refined/iterations"  # the stem of the snapshot arrays and of their index
ITERATIONS_INDEX = ITERATIONS + ".json"

# animate stage
TRANSFER = "animation/transfer.npz"
USD = "animation/pieces.usdc"


def field(name: str) -> str:
    """A field on the grid (``zeta``, ``xi``, ``psi``, ``distance``)."""
    return f"fields/{name}.npy"


def piece(c: int) -> str:
    """Piece ``c`` in material space."""
    return f"pieces/piece_{c:03d}.ply"


def frame(number: int, suffix: str = ".ply") -> str:
    """All pieces at the frame numbered ``number`` as the input numbers it
    (:meth:`fracture.coarse.surface.SourceFrames.file_numbers`)."""
    return f"frames/frame_{number:04d}{suffix}"


# What reading a damaged run file raises (a truncated array or archive, bad JSON or YAML, a missing key).
READ_ERRORS = (OSError, ValueError, KeyError, TypeError, IndexError, EOFError, zipfile.BadZipFile, yaml.YAMLError)


@contextmanager
def reading(run: str | Path, rel: str, doing: str):
    """Say in one line which of the run's files cannot be read while ``doing`` something, and why:
    ``RUN: DOING, REL cannot be read (WHY); run the config again to write it whole``."""
    try:
        yield
    except InputError:
        raise
    except READ_ERRORS as exc:
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"{run}: {doing}, {rel} cannot be read ({why}); run the config again to write it "
                         "whole") from None


def read_manifest(run: str | Path) -> dict:
    return manifest_object(json.loads((Path(run) / MANIFEST).read_text(encoding="utf-8")), Path(run) / MANIFEST)


def not_a_sweep(run: str | Path, doing: str) -> None:
    """An InputError when ``run`` is a sweep's folder (its ``sweep.json``), which holds runs but is none: name
    one of its points."""
    run = Path(run)
    if (run / "sweep.json").is_file():
        points = sorted(p.name for p in run.iterdir() if (p / MANIFEST).is_file())
        example = f", e.g. {run / points[0]}" if points else " (none has finished)"
        raise InputError(f"{run}: a sweep, not a run; {doing} one of its points{example}")


def manifest_object(data, path: str | Path) -> dict:
    """``data`` read from the manifest at ``path``, if it is a JSON object (a run writes one); else an
    InputError."""
    if not isinstance(data, dict):
        raise InputError(f"{path}: holds a JSON {type(data).__name__}; expected a run's manifest, a JSON object (run "
                         "the config again to write it whole)")
    return data


def read_grid(run: str | Path):
    """The field grid (:class:`fields.grid.Grid`)."""
    from fields.grid import Grid

    return Grid.from_dict(json.loads((Path(run) / GRID).read_text(encoding="utf-8")))


def read_field(run: str | Path, name: str) -> np.ndarray:
    return np.load(Path(run) / field(name))


def read_surface(run: str | Path, rel: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of a surface of the run (``EXTERIOR``, ``COARSE_SURFACE``, ``REFINED_SURFACE``,
    ``piece(c)``)."""
    from fracture.io.ply import read_ply

    return read_ply(Path(run) / rel)[:2]

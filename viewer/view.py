"""What the panels show and where their cameras stand: the records of a view file (``view:``) and of
``fracref render``'s options, kept apart from :mod:`viewer.looks` and Open3D, so that the command line
checks a render's request against its run before the renderer's libraries load (seconds of imports for
an answer that is one line)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from fracture.errors import InputError
from viewer.data import FIELDS, RunData

# The colour maps of the fracture surface, by what it is coloured by.
SURFACE_CMAPS = {"psi": "coolwarm", "speed": "viridis"}
COLOR_BY = tuple(SURFACE_CMAPS)


@dataclass
class View:
    """What the panels show: each field is a control of the window and part of a view file (``view:``);
    most are also options of ``fracref render``."""

    field: str = "psi"
    axis: str = "z"
    offset: float = 0.5
    level: int = 0
    iteration: int = -1  # -1: the last
    color_by: str = "psi"
    frame: int = 0  # 0-based; -1: the last
    overlay_coarse: bool = False
    cutaway: bool = False

    def check(self, run: RunData) -> "View":
        """This view with ``iteration`` and ``frame`` resolved (-1: the last), or an error naming the bad
        value and what is allowed."""
        if self.field not in FIELDS:
            raise InputError(f"field must be one of {', '.join(FIELDS)}, got {self.field!r}")
        if self.axis not in ("x", "y", "z"):
            raise InputError(f"axis must be x, y or z, got {self.axis!r}")
        if not 0.0 <= self.offset <= 1.0:
            raise InputError(f"slice offset must be in [0, 1], got {self.offset}")
        if self.color_by not in COLOR_BY:
            raise InputError(f"colour must be one of {', '.join(COLOR_BY)}, got {self.color_by!r}")
        if not 0 <= self.level < run.pyramid_levels:
            raise InputError(f"pyramid level must be in 0..{run.pyramid_levels - 1}, got {self.level}")
        v = View(**asdict(self))
        if run.has_iterations and v.iteration < 0:
            v.iteration = len(run.iterations) + v.iteration
        if v.frame < 0 and run.has_animation:
            v.frame = run.n_frames + v.frame
        return v


@dataclass
class CameraPose:
    """A camera: the point it looks at, where it stands, which way is up, and its vertical field of view
    in degrees."""

    center: np.ndarray
    eye: np.ndarray
    up: np.ndarray
    fov: float = 35.0

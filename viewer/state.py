"""What the panels show and from where, as a config's ``view:`` section.

The same section is a *view file* (``Save view`` in the window, ``--camera FILE``
for ``fracref view`` and ``fracref render``) and part of the config that
``Save config`` writes, so either kind of file can be given as ``--camera``:
the slice, the iteration, the frame and each panel's camera come back as
they were on screen. A camera left ``null`` is fitted to its panel.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import yaml

from fracture.io.atomic import atomic_write_text
from fracture.pipeline.config import read_yaml
from fracture.errors import ConfigError
from fracture.pipeline.schema import ViewSection, validate
from viewer.view import CameraPose, View
from viewer.tolerances import view_tol

PANELS = ("material", "iterations", "animation")


@dataclass
class ViewState:
    """The panels' settings and, per panel, a camera (None: fitted to the panel)."""

    view: View = field(default_factory=View)
    cameras: dict[str, CameraPose | None] = field(default_factory=lambda: dict.fromkeys(PANELS))

    def to_section(self) -> dict:
        """The config's ``view:`` section."""
        v = asdict(self.view)
        out = {k: v[k] for k in ViewSection.model_fields if k != "cameras"}
        out["frame"] = self.view.frame + 1
        out["cameras"] = {}
        for panel in PANELS:
            pose = self.cameras.get(panel)
            out["cameras"][panel] = ({"eye": None, "center": None, "up": None, "fov": 35.0} if pose is None else
                                     {"eye": _list(pose.eye), "center": _list(pose.center), "up": _list(pose.up),
                                      "fov": float(pose.fov)})
        return out


def _list(x) -> list[float]:
    return [float(c) for c in np.asarray(x, np.float64)]


def from_section(section: dict | None, where: str) -> ViewState:
    """A config's ``view:`` section (validated; defaults for what it leaves out) as a :class:`ViewState`."""
    section = validate({} if section is None else section, lambda key: where, ViewSection, prefix="view")
    view = View(**{k: getattr(section, k) for k in ("field", "axis", "offset", "level", "cutaway", "iteration",
                                                    "color_by", "overlay_coarse")}, frame=section.frame - 1)
    cameras = {}
    for panel in PANELS:
        c = getattr(section.cameras, panel).model_dump()
        given = [c[k] is not None for k in ("eye", "center", "up")]
        if not any(given):
            cameras[panel] = None
            continue
        key = f"view.cameras.{panel}"
        if not all(given):
            raise ConfigError(where, key, "got only some of eye, center and up; expected all three (or none: fitted)")
        eye, center, up = (np.array(c[k], np.float64) for k in ("eye", "center", "up"))
        forward = center - eye
        if np.linalg.norm(forward) < view_tol.direction:
            raise ConfigError(where, key, "eye and center are the same point; expected a camera looking somewhere")
        across = np.linalg.norm(np.cross(forward, up))
        if across < view_tol.parallel * np.linalg.norm(forward) * max(np.linalg.norm(up), view_tol.direction):
            raise ConfigError(where, f"{key}.up", "up is along the viewing direction (or zero); expected a direction "
                              "across it")
        cameras[panel] = CameraPose(center, eye, up, c["fov"])
    return ViewState(view, cameras)


def read_view_file(path: str | Path) -> ViewState:
    """The ``view:`` section of a view file or a config file."""
    path = Path(path)
    data = read_yaml(path)
    if "view" not in data:
        raise ConfigError(str(path), "view", "no view: section; expected a file written by Save view or Save config "
                          "(view: field, axis, ..., cameras: material: eye, center, up, fov)")
    return from_section(data["view"], str(path))


def write_view_file(path: str | Path, state: ViewState) -> Path:
    """Write ``state`` as a view file (atomically); it reads back the same."""
    path = Path(path)
    text = "# fracref view: the panels' settings and cameras (fracref view/render --camera FILE)\n"
    text += yaml.safe_dump({"view": state.to_section()}, sort_keys=False, default_flow_style=None, width=100)
    atomic_write_text(path, text)
    return path

"""The viewer's side panel: a sweep's points, the config's tunable numbers (re-run, save), the status line,
playback speed and the export settings."""

from __future__ import annotations

import copy
import textwrap

from open3d.visualization import gui

from fracture.pipeline.config import explain
from viewer.panels import combobox
from viewer.state import PANELS

SIDE_WIDTH_EM = 20
PLAY_FPS = 4  # images a second while playing (the side panel's "play speed")
# Config numbers the side panel offers (sections; every int or float leaf under them, and the strength layers').
TUNABLE_SECTIONS = ("psi", "stress", "pyramid", "refine")


def tunables(cfg: dict) -> list[tuple[str, object]]:
    """``(key path, value)`` of the config's tunable numbers, e.g. ``("refine.step", 0.25)``."""
    out = [("seed", cfg["seed"])]
    for sec in TUNABLE_SECTIONS:
        for k, v in cfg.get(sec, {}).items():
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                out.append((f"{sec}.{k}", v))
    for i, layer in enumerate(cfg.get("strength", {}).get("layers", [])):
        for k, v in layer.items():
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                out.append((f"strength.layers.{i}.{k}", v))
    return out


def _schema_key(cfg: dict, key: str) -> str:
    """The config schema's name of a tunable: a strength layer's key by its kind, not its index."""
    parts = key.split(".")
    if parts[:2] == ["strength", "layers"] and len(parts) == 4:
        parts[2] = cfg["strength"]["layers"][int(parts[2])]["kind"]
    return ".".join(parts)


def set_key(cfg: dict, path: str, value) -> None:
    node = cfg
    parts = path.split(".")
    for p in parts[:-1]:
        node = node[int(p)] if isinstance(node, list) else node[p]
    node[parts[-1]] = value


def number_edit(value, lo, hi) -> gui.NumberEdit:
    edit = gui.NumberEdit(gui.NumberEdit.INT if isinstance(value, int) else gui.NumberEdit.DOUBLE)
    edit.set_limits(lo, hi)
    if isinstance(value, int):
        edit.int_value = value
    else:
        edit.double_value = value
        edit.decimal_precision = 2
    return edit


class SidePanel:
    """The side panel of ``window`` (the :class:`viewer.app.Viewer`); its buttons call the window's
    methods."""

    def __init__(self, window):
        self.w = window
        self.widget = self._build(window.em)

    def _build(self, em: float) -> gui.Widget:
        w = self.w
        side = gui.ScrollableVert(0.25 * em, gui.Margins(0.5 * em, 0.5 * em, 0.5 * em, 0.5 * em))
        if w.sweep:
            side.add_child(gui.Label("Sweep point"))
            labels = [p.label for p in w.sweep]
            self.point_box = combobox(labels, lambda text: w.show_point(labels.index(text)))
            side.add_child(self.point_box)
            b = gui.Button("flip to the point before (F)")
            b.set_on_clicked(w.flip_points)
            side.add_child(b)
        side.add_child(gui.Label("Parameters"))
        self._parameters(side, em)
        buttons = gui.Horiz(0.5 * em)
        for text, handler in (("Re-run", w.rerun), ("Save config", lambda: w.save_config()),
                              ("Save view", lambda: w.save_view())):
            b = gui.Button(text)
            b.set_on_clicked(handler)
            buttons.add_child(b)
        side.add_child(buttons)
        self.status = gui.Label("ready")
        self.status_text = "ready"
        side.add_child(self.status)

        side.add_child(gui.Label("Playback"))
        grid = gui.VGrid(2, 0.25 * em)
        self.play_fps = number_edit(PLAY_FPS, 1, 60)
        grid.add_child(gui.Label("images / s"))
        grid.add_child(self.play_fps)
        side.add_child(grid)

        side.add_child(gui.Label("Export"))
        grid = gui.VGrid(2, 0.25 * em)
        self.export_w, self.export_h = number_edit(1280, 64, 8192), number_edit(720, 64, 8192)
        self.export_fps = number_edit(24, 1, 240)
        self.export_scale = number_edit(1, 1, 4)
        self.export_seconds = number_edit(0.25, 0.01, 60.0)
        self.export_hold = number_edit(1.0, 0.0, 60.0)
        for label, edit in (("width", self.export_w), ("height", self.export_h), ("fps", self.export_fps),
                            ("supersample", self.export_scale), ("s / iteration", self.export_seconds),
                            ("hold s", self.export_hold)):
            grid.add_child(gui.Label(label))
            grid.add_child(edit)
        side.add_child(grid)
        self.transparent_box = gui.Checkbox("transparent background (PNG)")
        side.add_child(self.transparent_box)
        row = gui.Horiz(0.5 * em)
        self.shot_box = combobox(("all panels",) + PANELS + ("coarse vs refined",))
        row.add_child(self.shot_box)
        b = gui.Button("Screenshot")
        b.set_on_clicked(lambda: w.exports.screenshot(self.shot_box.selected_text))
        row.add_child(b)
        side.add_child(row)
        row = gui.Horiz(0.5 * em)
        for what in ("iterations", "animation"):
            b = gui.Button(f"Video: {what}")
            b.set_on_clicked(lambda which=what: w.exports.export_video(which))
            row.add_child(b)
        side.add_child(row)
        return side

    def _parameters(self, side: gui.Widget, em: float) -> None:
        """One number box per tunable, in folding groups by section; editing one starts the re-run process."""
        self.edits: dict[str, gui.NumberEdit] = {}
        self.integer: set[str] = set()  # keys edited as integers
        cfg = self.w.cfg
        section = None
        for key, value in tunables(cfg):
            head = key.split(".")[0] if key != "seed" else "run"
            if head != section:
                section = head
                group = gui.CollapsableVert(head, 0.2 * em, gui.Margins(0.5 * em, 0, 0, 0))
                group.set_is_open(head in ("run", "psi"))  # the rest folded: Export stays in sight
                side.add_child(group)
            row = gui.Horiz(0.5 * em)
            edit = gui.NumberEdit(gui.NumberEdit.INT if isinstance(value, int) else gui.NumberEdit.DOUBLE)
            if isinstance(value, int):
                edit.int_value = value
                self.integer.add(key)
            else:
                edit.double_value = value
                edit.decimal_precision = 4
            label = gui.Label(key.split(".", 1)[-1] if key != "seed" else "seed")
            label.tooltip = edit.tooltip = explain(_schema_key(cfg, key))  # what fracref config --explain says
            row.add_child(label)
            row.add_stretch()
            row.add_child(edit)
            group.add_child(row)
            edit.set_on_value_changed(lambda _value: self.w.rerunner.start())
            self.edits[key] = edit

    def show_values(self, cfg: dict) -> None:
        """The number boxes set to ``cfg``'s values (a sweep point's)."""
        for key, value in tunables(cfg):
            if key in self.edits:
                if key in self.integer:
                    self.edits[key].int_value = int(value)
                else:
                    self.edits[key].double_value = float(value)

    def edited(self, cfg: dict) -> dict:
        """A copy of ``cfg`` with the number boxes' values."""
        out = copy.deepcopy(cfg)
        for key, edit in self.edits.items():
            set_key(out, key, edit.int_value if key in self.integer else edit.double_value)
        return out

    def say(self, text: str) -> None:
        """The status line, wrapped to the panel's width (the whole text stays in ``status_text``)."""
        self.status_text = text
        lines = textwrap.wrap(text, width=int(1.9 * SIDE_WIDTH_EM), break_long_words=True) or [""]
        self.status.text = "\n".join(lines[:4])


__all__ = ["SIDE_WIDTH_EM", "SidePanel", "number_edit", "set_key", "tunables"]

"""``fracref view CONFIG_OR_RUN_DIR``: the research viewer window.

Three panels side by side, each an Open3D SceneWidget with its controls
below it:

1. material space: a slice of zeta, xi or psi (field, axis, offset, pyramid
   level) with a colour bar, the coarse (wireframe) and refined fracture
   surfaces and a see-through exterior;
2. iterations: the fracture surface at iteration k coloured by psi or
   speed (slider, step buttons, play), with iteration, triangles and energy;
3. animation: the high-resolution pieces at frame t (slider, play), with
   the coarse pieces as an optional see-through overlay.

The side panel binds the config's tunable numbers; "Re-run" runs the
pipeline on a worker thread into a new run directory (never over the shown
one) while the iteration panel follows the refinement live; errors go to a
message box and the status line. "Save config" writes YAML that reproduces
the run on screen. Screenshots (one panel or all three, chosen size) and
videos (iterations or animation) are written next to the run.
"""

from __future__ import annotations

import copy
import threading
import time
import traceback
from dataclasses import replace
from pathlib import Path

import numpy as np
import open3d as o3d
from open3d.visualization import gui, rendering

from fields.colormap import colorbar
from fracture.io import layout
from fracture.io.atomic import atomic_write_text
from fracture.errors import ConfigError, InputError, ResultError, StageError
from fracture.pipeline.config import Config, explain
from viewer.data import FIELDS, RunData, Surface, SweepPoint, read_sweep
from viewer.exports import Exports, numbered
from viewer.looks import (
    COLOR_BY, FIELD_CMAPS, SURFACE_CMAPS, CameraPose, animation_box, animation_pose, frame_box, iteration_box,
    iteration_caption, iteration_pose, scene_box, set_cutaway, set_frame, set_slice, set_surface, show_context,
    show_material, show_stage, slice_pose,
)
from viewer.lifetime import Lifetime
from viewer.rerun import RerunWorker
from viewer.state import PANELS, ViewState, from_section, write_view_file
from viewer.tolerances import view_tol

PRESETS = ("iso", "front", "side", "top")
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


def _combobox(items, on_change=None) -> gui.Combobox:
    box = gui.Combobox()
    for item in items:
        box.add_item(item)
    if on_change is not None:
        box.set_on_selection_changed(lambda text, index: on_change(text))
    return box


def _number_edit(value, lo, hi) -> gui.NumberEdit:
    edit = gui.NumberEdit(gui.NumberEdit.INT if isinstance(value, int) else gui.NumberEdit.DOUBLE)
    edit.set_limits(lo, hi)
    if isinstance(value, int):
        edit.int_value = value
    else:
        edit.double_value = value
        edit.decimal_precision = 2
    return edit


def _bar_row(em: float) -> tuple[gui.Widget, gui.Label, gui.ImageWidget, gui.Label]:
    """A horizontal colour bar with its low and high values beside it (the panel's key)."""
    row = gui.Horiz(0.5 * em)
    low, high = gui.Label("        "), gui.Label("                ")
    image = gui.ImageWidget(o3d.geometry.Image(np.zeros((12, 200, 3), np.uint8)))
    for w in (low, image, high):
        row.add_child(w)
    return row, low, image, high


class Viewer:
    """The window and its state; the handlers are methods, so scripts and tests drive it like a user."""

    def __init__(self, run: RunData, width: int = 1800, height: int = 900, start: ViewState | None = None,
                 sweep: list[SweepPoint] | None = None):
        self.app = gui.Application.instance
        self.run = run
        # a sweep's finished points (fracref sweep), the one shown and the one shown before it
        self.sweep = list(sweep or [])
        self.point, self.previous_point = 0, 0
        # the view to start with: ``start`` (a view file), else the run's config ``view:`` section
        start = start or from_section(run.config.get("view"), str(run.dir / layout.CONFIG))
        self.view = start.view  # checked against the run by load()
        self.window = self.app.create_window(f"fracref: {run.name}", width, height)
        self.window.set_on_layout(self._layout)
        self.window.set_on_tick_event(self._tick)
        self.window.set_on_close(self._on_close)
        self.em = self.window.theme.font_size
        self.scenes = []
        for _ in PANELS:
            sw = gui.SceneWidget()
            sw.scene = rendering.Open3DScene(self.window.renderer)
            sw.set_on_mouse(self._on_mouse(len(self.scenes)))
            sw.set_on_key(self._on_key(len(self.scenes)))
            self.window.add_child(sw)
            self.scenes.append(sw)
        self.controls = [self._material_controls(), self._iteration_controls(), self._animation_controls()]
        for c in self.controls:
            self.window.add_child(c)
        self.side = self._side_panel()
        self.window.add_child(self.side)
        self.poses: list[CameraPose | None] = [None, None, None]
        self._fitted = [False, False, False]  # whether each pose was fitted to its panel's real shape
        self.playing = {"iterations": False, "animation": False}
        self._last_step = 0.0
        self._sync_from: int | None = None
        self._job = None  # a generator stepped on ticks (video export)
        self.exports = Exports(self)  # screenshots and videos of the panels (viewer/exports.py)
        self._worker: threading.Thread | None = None
        # re-runs go to one child process (viewer/rerun.py), started when a parameter is first
        # edited, so that it has imported the pipeline by the re-run; a window only looked at starts none
        self._rerunner = RerunWorker()
        self._live: dict | None = None
        self._live_lock = threading.Lock()
        self.rerun_dirs: list[Path] = []
        self.errors: list[str] = []
        self.live_updates = 0  # iterations of a re-run drawn while it ran
        self.show_view(start)

    # -- layout ---------------------------------------------------------------------------

    def _layout(self, ctx) -> None:
        r = self.window.content_rect
        side_w = SIDE_WIDTH_EM * self.em
        ctrl_h = max(c.calc_preferred_size(ctx, gui.Widget.Constraints()).height for c in self.controls)
        pw = (r.width - side_w) // 3
        for i, (sw, c) in enumerate(zip(self.scenes, self.controls)):
            sw.frame = gui.Rect(r.x + i * pw, r.y, pw, r.height - ctrl_h)
            c.frame = gui.Rect(r.x + i * pw, r.y + r.height - ctrl_h, pw, ctrl_h)
        self.side.frame = gui.Rect(r.x + 3 * pw, r.y, r.width - 3 * pw, r.height)
        for i in range(len(self.scenes)):  # cameras fitted before the panels had a size: fit them now
            if self.poses[i] is not None and not self._fitted[i]:
                self.poses[i] = None
                self._pose(i)

    def _material_controls(self) -> gui.Widget:
        em = self.em
        v = gui.Vert(0.25 * em, gui.Margins(0.5 * em, 0.25 * em, 0.5 * em, 0.25 * em))
        row = gui.Horiz(0.5 * em)
        self.field_box = _combobox(FIELDS, self.set_field)
        self.axis_box = _combobox("xyz", self.set_axis)
        row.add_child(gui.Label("field"))
        row.add_child(self.field_box)
        row.add_child(gui.Label("axis"))
        row.add_child(self.axis_box)
        v.add_child(row)
        row = gui.Horiz(0.5 * em)
        row.add_child(gui.Label("offset"))
        self.offset_slider = gui.Slider(gui.Slider.DOUBLE)
        self.offset_slider.set_limits(0.0, 1.0)
        self.offset_slider.set_on_value_changed(self.set_offset)
        row.add_child(self.offset_slider)
        v.add_child(row)
        row = gui.Horiz(0.5 * em)
        row.add_child(gui.Label("level"))
        self.level_slider = gui.Slider(gui.Slider.INT)
        self.level_slider.set_on_value_changed(lambda x: self.set_level(int(x)))
        row.add_child(self.level_slider)
        self.cutaway_box = gui.Checkbox("cutaway")
        self.cutaway_box.set_on_checked(self.set_cutaway)
        row.add_child(self.cutaway_box)
        v.add_child(row)
        self.slice_bar = _bar_row(em)
        v.add_child(self.slice_bar[0])
        return v

    def _iteration_controls(self) -> gui.Widget:
        em = self.em
        v = gui.Vert(0.25 * em, gui.Margins(0.5 * em, 0.25 * em, 0.5 * em, 0.25 * em))
        row = gui.Horiz(0.5 * em)
        self.iter_slider = gui.Slider(gui.Slider.INT)
        self.iter_slider.set_on_value_changed(lambda x: self.set_iteration(int(x)))
        row.add_child(self.iter_slider)
        v.add_child(row)
        row = gui.Horiz(0.5 * em)
        for text, step in (("<", -1), (">", 1)):
            b = gui.Button(text)
            b.set_on_clicked(lambda s=step: self.set_iteration(self.view.iteration + s))
            row.add_child(b)
        self.iter_play = gui.Button("play")
        self.iter_play.set_on_clicked(lambda: self.toggle_play("iterations"))
        row.add_child(self.iter_play)
        row.add_child(gui.Label("colour"))
        self.color_box = _combobox(COLOR_BY, self.set_color_by)
        row.add_child(self.color_box)
        v.add_child(row)
        self.surface_bar = _bar_row(em)
        v.add_child(self.surface_bar[0])
        self.iter_label = gui.Label("")
        v.add_child(self.iter_label)
        return v

    def _animation_controls(self) -> gui.Widget:
        em = self.em
        v = gui.Vert(0.25 * em, gui.Margins(0.5 * em, 0.25 * em, 0.5 * em, 0.25 * em))
        self.frame_slider = gui.Slider(gui.Slider.INT)
        self.frame_slider.set_on_value_changed(lambda x: self.set_frame(int(x) - 1))
        v.add_child(self.frame_slider)
        row = gui.Horiz(0.5 * em)
        self.frame_play = gui.Button("play")
        self.frame_play.set_on_clicked(lambda: self.toggle_play("animation"))
        row.add_child(self.frame_play)
        self.overlay_box = gui.Checkbox("coarse overlay")
        self.overlay_box.set_on_checked(self.set_overlay)
        row.add_child(self.overlay_box)
        self.link_box = gui.Checkbox("link cameras")
        row.add_child(self.link_box)
        v.add_child(row)
        row = gui.Horiz(0.5 * em)
        b = gui.Button("reset view")
        b.set_on_clicked(lambda: self.reset_view())
        row.add_child(b)
        row.add_child(gui.Label("view"))
        self.preset_box = _combobox(PRESETS, self.set_preset)
        row.add_child(self.preset_box)
        v.add_child(row)
        self.frame_label = gui.Label("")
        v.add_child(self.frame_label)
        return v

    def _side_panel(self) -> gui.Widget:
        em = self.em
        side = gui.ScrollableVert(0.25 * em, gui.Margins(0.5 * em, 0.5 * em, 0.5 * em, 0.5 * em))
        if self.sweep:
            side.add_child(gui.Label("Sweep point"))
            labels = [p.label for p in self.sweep]
            self.point_box = _combobox(labels, lambda text: self.show_point(labels.index(text)))
            side.add_child(self.point_box)
            b = gui.Button("flip to the point before (F)")
            b.set_on_clicked(self.flip_points)
            side.add_child(b)
        side.add_child(gui.Label("Parameters"))
        self.edits: dict[str, gui.NumberEdit] = {}
        self._integer: set[str] = set()  # keys edited as integers
        section = None
        for key, value in tunables(self.cfg):
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
                self._integer.add(key)
            else:
                edit.double_value = value
                edit.decimal_precision = 4
            label = gui.Label(key.split(".", 1)[-1] if key != "seed" else "seed")
            label.tooltip = edit.tooltip = explain(_schema_key(self.cfg, key))  # what fracref config --explain says
            row.add_child(label)
            row.add_stretch()
            row.add_child(edit)
            group.add_child(row)
            edit.set_on_value_changed(lambda _value: self._rerunner.start())
            self.edits[key] = edit
        buttons = gui.Horiz(0.5 * em)
        for text, handler in (("Re-run", self.rerun), ("Save config", lambda: self.save_config()),
                              ("Save view", lambda: self.save_view())):
            b = gui.Button(text)
            b.set_on_clicked(handler)
            buttons.add_child(b)
        side.add_child(buttons)
        self.status = gui.Label("ready")
        side.add_child(self.status)

        side.add_child(gui.Label("Playback"))
        grid = gui.VGrid(2, 0.25 * em)
        self.play_fps = _number_edit(PLAY_FPS, 1, 60)
        grid.add_child(gui.Label("images / s"))
        grid.add_child(self.play_fps)
        side.add_child(grid)

        side.add_child(gui.Label("Export"))
        grid = gui.VGrid(2, 0.25 * em)
        self.export_w, self.export_h = _number_edit(1280, 64, 8192), _number_edit(720, 64, 8192)
        self.export_fps = _number_edit(24, 1, 240)
        self.export_scale = _number_edit(1, 1, 4)
        self.export_seconds = _number_edit(0.25, 0.01, 60.0)
        self.export_hold = _number_edit(1.0, 0.0, 60.0)
        for label, w in (("width", self.export_w), ("height", self.export_h), ("fps", self.export_fps),
                         ("supersample", self.export_scale), ("s / iteration", self.export_seconds),
                         ("hold s", self.export_hold)):
            grid.add_child(gui.Label(label))
            grid.add_child(w)
        side.add_child(grid)
        self.transparent_box = gui.Checkbox("transparent background (PNG)")
        side.add_child(self.transparent_box)
        row = gui.Horiz(0.5 * em)
        self.shot_box = _combobox(("all panels",) + PANELS + ("coarse vs refined",))
        row.add_child(self.shot_box)
        b = gui.Button("Screenshot")
        b.set_on_clicked(lambda: self.exports.screenshot(self.shot_box.selected_text))
        row.add_child(b)
        side.add_child(row)
        row = gui.Horiz(0.5 * em)
        for what in ("iterations", "animation"):
            b = gui.Button(f"Video: {what}")
            b.set_on_clicked(lambda w=what: self.exports.export_video(w))
            row.add_child(b)
        side.add_child(row)
        return side

    def say(self, text: str) -> None:
        """The status line, wrapped to the side panel's width (the whole text stays in ``status_text``)."""
        import textwrap

        self.status_text = text
        lines = textwrap.wrap(text, width=int(1.9 * SIDE_WIDTH_EM), break_long_words=True) or [""]
        self.status.text = "\n".join(lines[:4])

    # -- sweeps -------------------------------------------------------------------------------

    def show_point(self, k: int) -> None:
        """Show the sweep's point ``k`` in all panels with the same view and cameras (to compare), its
        parameters in the side panel."""
        if not 0 <= k < len(self.sweep) or (k == self.point and self.run.dir == self.sweep[k].dir):
            return
        try:
            run = RunData(self.sweep[k].dir)
        except InputError as exc:
            self.report_error("cannot show the sweep point", exc)
            return
        cameras = [self.current_pose(i) for i in range(len(self.scenes))]
        self.previous_point, self.point = self.point, k
        self.load(run, keep_view=True)
        for i, pose in enumerate(cameras):
            self.poses[i] = pose
            self._place(i, pose)
        for key, value in tunables(self.cfg):
            if key in self.edits:
                if key in self._integer:
                    self.edits[key].int_value = int(value)
                else:
                    self.edits[key].double_value = float(value)
        self.point_box.selected_index = k
        self.window.title = f"fracref: {self.sweep[k].name}"
        self.say(f"sweep point {k + 1} / {len(self.sweep)}: {self.sweep[k].label}")

    def flip_points(self) -> None:
        """Back to the point shown before (again: forth), to compare two points."""
        if self.sweep:
            self.show_point(self.previous_point)

    # -- loading and drawing -------------------------------------------------------------------

    def load(self, run: RunData, keep_view: bool = False) -> None:
        """Show ``run`` in all panels (after start-up or a re-run: the last iteration and the first frame,
        unless ``keep_view``)."""
        self.run = run
        self.view = (self.view if keep_view else replace(self.view, iteration=-1, frame=0)).check(run)
        n_it = len(run.iterations) if run.has_iterations else 1
        self.view = replace(self.view, iteration=int(np.clip(self.view.iteration, 0, n_it - 1)),
                            frame=int(np.clip(self.view.frame, 0, max(run.n_frames - 1, 0))))
        self.level_slider.set_limits(0, max(run.pyramid_levels - 1, 0))
        n_it = len(run.iterations) if run.has_iterations else 1
        self.iter_slider.set_limits(0, max(n_it - 1, 0))
        self.iter_slider.int_value = self.view.iteration
        self.frame_slider.set_limits(1, max(run.n_frames, 1))
        self.frame_slider.int_value = self.view.frame + 1
        self.offset_slider.double_value = self.view.offset
        self.level_slider.int_value = self.view.level
        self.field_box.selected_index = FIELDS.index(self.view.field)
        self.axis_box.selected_index = "xyz".index(self.view.axis)
        self.color_box.selected_index = COLOR_BY.index(self.view.color_by)
        self.cutaway_box.checked = self.view.cutaway
        self.overlay_box.checked = self.view.overlay_coarse
        self.poses = [None, None, None]
        show_material(self.scenes[0].scene, run)
        show_context(self.scenes[1].scene, run)
        show_stage(self.scenes[2].scene, run)
        self.draw_material()
        self.draw_iteration()
        self.draw_frame()

    def _aspect(self, i: int) -> float:
        f = self.scenes[i].frame
        return f.width / max(f.height, 1) if f.width > 0 else 1.0

    def subject_box(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """The box panel ``i`` keeps in view: the object, the fracture surface over all iterations,
        or the pieces over all frames."""
        if i == 1 and self.run.has_iterations:
            return iteration_box(self.run)
        if i == 2 and self.run.has_animation:
            return animation_box(self.run)
        return scene_box(self.run)

    def _pose(self, i: int) -> CameraPose:
        if self.poses[i] is None:
            a = self._aspect(i)
            if i == 0:
                pose = slice_pose(self.run, self.view, a)
            elif i == 1 and self.run.has_iterations:
                pose = iteration_pose(self.run, a)
            elif i == 2 and self.run.has_animation:
                pose = animation_pose(self.run, a)
            else:
                pose = frame_box(*scene_box(self.run), a)
            self.poses[i] = pose
            self._fitted[i] = self.scenes[i].frame.width > 0
            self._place(i, pose)
        return self.poses[i]

    def _place(self, i: int, pose: CameraPose) -> None:
        """Put panel ``i``'s camera at ``pose``, with the widget's rotation centre at the pose's
        centre and its clipping planes from the panel's subject, so that dragging turns the
        subject about its middle."""
        sw = self.scenes[i]
        lo, hi = self.subject_box(i)
        lo, hi = np.minimum(lo, pose.center), np.maximum(hi, pose.center)
        sw.setup_camera(pose.fov, o3d.geometry.AxisAlignedBoundingBox(lo, hi), pose.center.astype(np.float32))
        sw.look_at(pose.center.astype(np.float32), pose.eye.astype(np.float32), pose.up.astype(np.float32))

    def reset_view(self, i: int | None = None) -> None:
        """Panel ``i``'s camera (every panel's by default) back to its fitted view."""
        for j in range(len(self.scenes)) if i is None else (i,):
            self.poses[j] = None
            self._pose(j)
            self.scenes[j].force_redraw()

    def _fitted_distance(self, i: int) -> float:
        pose = self._pose(i)
        return float(np.linalg.norm(pose.eye - pose.center))

    def current_pose(self, i: int) -> CameraPose:
        """Panel ``i``'s camera as the user left it; the centre is on the view axis at the fitted distance."""
        cam = self.scenes[i].scene.camera
        M = np.asarray(cam.get_model_matrix(), np.float64)
        eye, forward, up = M[:3, 3], -M[:3, 2], M[:3, 1]
        return CameraPose(eye + self._fitted_distance(i) * forward, eye, up, float(cam.get_field_of_view()))

    def _look_along(self, j: int, forward: np.ndarray, up: np.ndarray) -> None:
        """Panel ``j`` looking along ``forward`` at its own subject, from its fitted distance."""
        center = self._pose(j).center
        forward = forward / max(np.linalg.norm(forward), view_tol.direction)
        eye = center - self._fitted_distance(j) * forward
        self.scenes[j].look_at(center.astype(np.float32), eye.astype(np.float32), np.asarray(up, np.float32))
        self.scenes[j].force_redraw()

    def _follow(self, src: int) -> None:
        """Linked cameras: every other panel looks from the same direction, with the same up,
        at its own subject from its own fitted distance (the subjects differ in size and place)."""
        cur = self.current_pose(src)
        for j in range(len(self.scenes)):
            if j != src:
                self._look_along(j, cur.center - cur.eye, cur.up)

    @property
    def cfg(self) -> dict:
        """The config of the run on screen (the side panel's starting values)."""
        return self.run.config

    @property
    def _iter_range(self) -> tuple[float, float] | None:
        return self.run.surface_range(self.view.color_by) if self.run.has_iterations else None

    @staticmethod
    def _show_bar(row, cmap: str, lo: float, hi: float, name: str) -> None:
        _, low, image, high = row
        image.update_image(o3d.geometry.Image(colorbar(cmap, 200, 12, vertical=False)))  # low values at the left
        low.text, high.text = f"{lo:.3g}", f"{hi:.3g} ({name})"

    def draw_material(self) -> None:
        lo, hi = set_slice(self.scenes[0].scene, self.run, self.view)
        set_cutaway(self.scenes[0].scene, self.run, self.view)
        self._show_bar(self.slice_bar, FIELD_CMAPS[self.view.field], lo, hi, self.view.field)
        self._pose(0)
        self.scenes[0].force_redraw()

    def draw_iteration(self, live: dict | None = None) -> None:
        scene = self.scenes[1].scene
        if live is not None:  # a re-run in progress: its latest iteration
            c = live[self.view.color_by]
            rng = self._iter_range or (float(c.min()), float(c.max()))
            surface = Surface(live["positions"], live["faces"], {k: live[k] for k in COLOR_BY})
            set_surface(scene, surface, self.view.color_by, rng)
            self.iter_label.text = (f"re-run: iteration {live['iteration']}, {len(live['faces'])} triangles, "
                                    f"E = {live['energy']:.4g}")
        elif self.run.has_iterations:
            set_surface(scene, self.run.iteration(self.view.iteration), self.view.color_by, self._iter_range)
            self._show_bar(self.surface_bar, SURFACE_CMAPS[self.view.color_by], *self._iter_range, self.view.color_by)
            self.iter_label.text = iteration_caption(self.run, self.view.iteration)
        else:
            self.iter_label.text = "no iterations in this run (refine.snapshots: false, or stopped early)"
        self._pose(1)
        self.scenes[1].force_redraw()

    def draw_frame(self) -> None:
        if self.run.has_animation:
            set_frame(self.scenes[2].scene, self.run, self.view)
            self.frame_label.text = f"frame {self.view.frame + 1} / {self.run.n_frames}, {len(self.run.piece_faces)} pieces"
        else:
            self.frame_label.text = "no animation in this run (stopped before the animate stage)"
        self._pose(2)
        self.scenes[2].force_redraw()

    # -- handlers ---------------------------------------------------------------------------------

    def set_field(self, name: str) -> None:
        self.view = replace(self.view, field=name)
        self.draw_material()

    def set_cutaway(self, on: bool) -> None:
        self.view = replace(self.view, cutaway=bool(on))
        self.cutaway_box.checked = bool(on)
        self.draw_material()

    def set_axis(self, axis: str) -> None:
        self.view = replace(self.view, axis=axis)
        self.poses[0] = None
        self.draw_material()

    def set_offset(self, offset: float) -> None:
        self.view = replace(self.view, offset=float(np.clip(offset, 0.0, 1.0)))
        self.offset_slider.double_value = self.view.offset
        self.draw_material()

    def set_level(self, level: int) -> None:
        self.view = replace(self.view, level=int(np.clip(level, 0, self.run.pyramid_levels - 1)))
        self.level_slider.int_value = self.view.level
        self.draw_material()

    def set_iteration(self, k: int) -> None:
        if not self.run.has_iterations:
            return
        k = int(np.clip(k, 0, len(self.run.iterations) - 1))
        self.view = replace(self.view, iteration=k)
        self.iter_slider.int_value = k
        self.draw_iteration()

    def set_color_by(self, name: str) -> None:
        self.view = replace(self.view, color_by=name)
        self.draw_iteration()

    def set_frame(self, t: int) -> None:
        if not self.run.has_animation:
            return
        t = int(np.clip(t, 0, self.run.n_frames - 1))
        self.view = replace(self.view, frame=t)
        self.frame_slider.int_value = t + 1
        self.draw_frame()

    def set_overlay(self, on: bool) -> None:
        self.view = replace(self.view, overlay_coarse=bool(on))
        self.overlay_box.checked = bool(on)
        self.draw_frame()

    def toggle_play(self, which: str) -> None:
        self.playing[which] = not self.playing[which]
        (self.iter_play if which == "iterations" else self.frame_play).text = "pause" if self.playing[which] else "play"

    def _on_mouse(self, i: int):
        def handler(event):
            if self.link_box.checked and event.type in (gui.MouseEvent.Type.DRAG, gui.MouseEvent.Type.WHEEL,
                                                        gui.MouseEvent.Type.BUTTON_UP):
                self._sync_from = i
            return gui.Widget.EventCallbackResult.IGNORED
        return handler

    def _on_key(self, i: int):
        """Hotkeys over a panel: space play/pause, arrows step, R reset the view, S screenshot, F flip between
        two sweep points."""
        def handler(event):
            if event.type != gui.KeyEvent.Type.DOWN:
                return gui.Widget.EventCallbackResult.IGNORED
            which = "animation" if i == 2 else "iterations"
            if event.key == gui.KeyName.SPACE:
                self.toggle_play(which)
            elif event.key in (gui.KeyName.LEFT, gui.KeyName.RIGHT):
                step = 1 if event.key == gui.KeyName.RIGHT else -1
                if which == "animation":
                    self.set_frame(self.view.frame + step)
                else:
                    self.set_iteration(self.view.iteration + step)
            elif event.key == gui.KeyName.R:
                self.reset_view(None if self.link_box.checked else i)
            elif event.key == gui.KeyName.S:
                self.exports.screenshot(self.shot_box.selected_text)
            elif event.key == gui.KeyName.F and self.sweep:
                self.flip_points()
            else:
                return gui.Widget.EventCallbackResult.IGNORED
            return gui.Widget.EventCallbackResult.CONSUMED
        return handler

    def set_preset(self, name: str) -> None:
        """Every panel seen from the front, the side, the top or in three-quarter view (``PRESETS``),
        with the run's up axis up, each at its own fitted distance."""
        up = "xyz".index(self.run.up_axis)
        a, b = [k for k in range(3) if k != up]
        E = np.eye(3)
        direction, screen_up = {
            "front": (-E[a], E[up]), "side": (E[b], E[up]), "top": (E[up], E[b]),
            "iso": (E[b] - E[a] + 0.8 * E[up], E[up]),
        }[name]
        for j in range(len(self.scenes)):
            self._look_along(j, -direction, screen_up)

    def _tick(self) -> bool:
        redraw = False
        if self._sync_from is not None:  # linked cameras follow the one the user moved
            self._follow(self._sync_from)
            self._sync_from = None
            redraw = True
        now = time.monotonic()
        if now - self._last_step >= 1.0 / max(self.play_fps.int_value, 1) and any(self.playing.values()):
            self._last_step = now
            if self.playing["iterations"] and self.run.has_iterations:
                self.set_iteration((self.view.iteration + 1) % len(self.run.iterations))
            if self.playing["animation"] and self.run.has_animation:
                self.set_frame((self.view.frame + 1) % self.run.n_frames)
            redraw = True
        with self._live_lock:
            live, self._live = self._live, None
        if live is not None:
            self.draw_iteration(live)
            self.live_updates += 1
            redraw = True
        if self._job is not None:
            try:
                next(self._job)
            except StopIteration:
                self._job = None
            except Exception as exc:  # noqa: BLE001 - shown to the user, not lost
                self._job = None
                self.report_error("export failed", exc)
            redraw = True
        return redraw

    def end(self) -> None:
        """End what the window started: its re-run child (after the current re-run if it ends within a
        second, else at once)."""
        self._rerunner.stop()

    def _on_close(self) -> bool:
        if self._worker is not None and self._worker.is_alive():
            self.say("a re-run is still going; it ends with the window")
        self._rerunner.close()
        return True

    # -- re-run and config ---------------------------------------------------------------------------

    def edited_config(self) -> dict:
        cfg = copy.deepcopy(self.cfg)
        for key, edit in self.edits.items():
            set_key(cfg, key, edit.int_value if key in self._integer else edit.double_value)
        return cfg

    def checked_config(self) -> tuple[Config, str]:
        """The side panel's config, validated as ``fracref run`` would read it, and its YAML."""
        from fracture.pipeline.config import check_config, dump_config

        cfg = self.edited_config()
        cfg["view"] = self.view_state().to_section()  # the slice, iteration, frame and cameras on screen
        cfg = check_config(cfg, "the viewer's parameters")
        return cfg, dump_config(cfg)

    def save_config(self, path: str | Path | None = None) -> Path | None:
        """Write the on-screen parameters as YAML (checked by loading it back); returns the file."""
        path = Path(path) if path is not None else numbered(self.run.dir.parent, f"{self.run.name}_viewer", ".yaml")
        try:
            atomic_write_text(path, self.checked_config()[1])
        except (ConfigError, OSError) as exc:
            self.report_error("cannot save the config", exc)
            return None
        self.say(f"saved {path}")
        return path

    def _next_run_dir(self) -> Path:
        base = self.run.dir
        root = base.parent / f"{base.name.split('.rerun')[0]}.rerun"
        k = 1
        while Path(f"{root}{k}").exists():
            k += 1
        return Path(f"{root}{k}")

    def rerun(self) -> None:
        """Run the pipeline with the side panel's parameters on a worker thread, into a new run directory."""
        if self._worker is not None and self._worker.is_alive():
            self.say("a re-run is already going")
            return
        out = self._next_run_dir()
        try:
            cfg = self.checked_config()[0]
        except (ConfigError, OSError) as exc:
            self.report_error("the parameters are not valid", exc)
            return
        self.say(f"re-running into {out} ...")

        def work():
            # the pipeline runs in the re-run process (viewer/rerun.py); this thread relays its
            # progress to the window
            import queue as queue_mod

            worker = self._rerunner
            worker.submit(cfg, str(out))
            while True:
                try:
                    event, data = worker.events.get(timeout=0.2)
                except queue_mod.Empty:
                    if not worker.alive:
                        self.app.post_to_main_thread(self.window, lambda: self.report_error(
                            "re-run failed", StageError(f"the run stopped (exit code {worker.exitcode})")))
                        return
                    continue
                if event == "stage":
                    self.app.post_to_main_thread(self.window, lambda n=data["name"]: self.say(f"re-run: {n} ..."))
                elif event == "iteration":
                    with self._live_lock:
                        self._live = data
                elif event == "done":
                    self.app.post_to_main_thread(self.window, lambda: self._rerun_done(out))
                    break
                elif event == "error":
                    self.app.post_to_main_thread(self.window, lambda e=data: self.report_error(
                        "re-run failed", StageError(e)))
                    break

        self._worker = threading.Thread(target=work, name="rerun", daemon=True)
        self._worker.start()

    def _rerun_done(self, out: Path) -> None:
        with self._live_lock:
            self._live = None
        self.rerun_dirs.append(out)
        self.load(RunData(out))
        self.window.title = f"fracref: {self.run.name} ({out.name})"
        self.say(f"re-run done: {out}")

    def report_error(self, what: str, exc: BaseException) -> None:
        known = isinstance(exc, (ConfigError, InputError, ResultError, StageError, OSError))
        text = f"{what}: {exc}" if known else f"{what}: {exc!r}\n{traceback.format_exc(limit=4)}"
        self.errors.append(text)
        self.say(text.splitlines()[0])
        self.window.show_message_box("fracref", text)

    # -- views ---------------------------------------------------------------------------------------

    def show_view(self, state: ViewState) -> None:
        """Show what ``state`` says (a view file's or a config's ``view:`` section): its slice,
        iteration, frame and colours, and its cameras (a panel without one is fitted)."""
        self.view = state.view
        self.load(self.run, keep_view=True)
        for i, panel in enumerate(PANELS):
            if state.cameras.get(panel) is not None:
                self.poses[i], self._fitted[i] = state.cameras[panel], True
                self._place(i, state.cameras[panel])
                self.scenes[i].force_redraw()

    def view_state(self) -> ViewState:
        """What the panels show and every panel's camera as the user left it."""
        return ViewState(self.view, {panel: self.current_pose(i) for i, panel in enumerate(PANELS)})

    def save_view(self, path: str | Path | None = None) -> Path | None:
        """Write the panels' settings and cameras as a view file (``--camera FILE`` of view and render)."""
        try:
            path = Path(path) if path else numbered(self.run.dir / "renders", "view", ".yaml")
            path.parent.mkdir(parents=True, exist_ok=True)
            write_view_file(path, self.view_state())
        except OSError as exc:
            self.report_error("cannot save the view", exc)
            return None
        self.say(f"saved {path}")
        return path


def open_target(target: Path, out: Path | None) -> RunData:
    """A run directory as is; a config is run first (into ``out`` or ``runs/<name>``, reused when complete)."""
    from fracture.pipeline import runner
    from fracture.pipeline.cache import StageCache
    from fracture.pipeline.config import load_config

    target = Path(target)
    if target.is_dir():
        return RunData(target)
    if not target.is_file():
        raise InputError(f"{target}: neither a run directory nor a config file")
    cfg = load_config(target)
    out = Path(out) if out is not None else Path("runs") / cfg.name
    if not (out / layout.MANIFEST).is_file():
        print(f"running {target} into {out} first ...")
        runner.run(cfg, out, progress=True, cache=StageCache())
    return RunData(out)


def main(target: Path, out: Path | None = None, width: int = 1800, height: int = 900,
         camera: Path | None = None) -> int:
    from viewer.state import read_view_file

    start = read_view_file(camera) if camera is not None else None  # a bad file is reported before any work
    sweep = read_sweep(target) if Path(target, "sweep.json").is_file() else None
    run = RunData(sweep[0].dir) if sweep else open_target(target, out)
    app = gui.Application.instance
    app.initialize()
    # the loop ends with the window, on SIGINT or SIGTERM, or with the display (viewer/lifetime.py)
    with Lifetime() as lifetime:
        viewer = Viewer(run, width, height, start, sweep)
        return lifetime.run(app, viewer.window.close, viewer.end)


__all__ = ["Viewer", "main", "open_target", "tunables"]

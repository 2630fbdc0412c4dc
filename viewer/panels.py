"""The viewer's three panels, each an Open3D SceneWidget with its controls below it and its camera.

1. :class:`MaterialPanel`: a slice of zeta, xi or psi (field, axis, offset,
   pyramid level) with a colour bar, the coarse (wireframe) and refined
   fracture surfaces and a see-through exterior;
2. :class:`IterationsPanel`: the fracture surface at iteration k coloured by
   psi or speed (slider, step buttons, play), with iteration, triangles and
   energy;
3. :class:`AnimationPanel`: the high-resolution pieces at frame t (slider,
   play), with the coarse pieces as an optional see-through overlay, and the
   cameras' shared controls (link, reset, preset views).

A panel reads and writes the window's run and view state (``window.run``,
``window.view``); its setters are what its controls call, so scripts and
tests drive it as a user would.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import open3d as o3d
from open3d.visualization import gui, rendering

from fields.colormap import colorbar
from viewer.data import FIELDS, RunData, Surface
from viewer.looks import (
    FIELD_CMAPS, SURFACE_CMAPS, CameraPose, animation_box, animation_pose, frame_box, ground_height,
    iteration_box, iteration_caption, iteration_pose, scene_box, set_cutaway, set_frame, set_slice, set_surface,
    show_context, show_material, show_stage, slice_pose,
)
from viewer.tolerances import view_tol
from viewer.view import COLOR_BY

PRESETS = ("iso", "front", "side", "top")


def combobox(items, on_change=None) -> gui.Combobox:
    box = gui.Combobox()
    for item in items:
        box.add_item(item)
    if on_change is not None:
        box.set_on_selection_changed(lambda text, index: on_change(text))
    return box


def _bar_row(em: float) -> tuple[gui.Widget, gui.Label, gui.ImageWidget, gui.Label]:
    """A horizontal colour bar with its low and high values beside it (the panel's key)."""
    row = gui.Horiz(0.5 * em)
    low, high = gui.Label("        "), gui.Label("                ")
    image = gui.ImageWidget(o3d.geometry.Image(np.zeros((12, 200, 3), np.uint8)))
    for w in (low, image, high):
        row.add_child(w)
    return row, low, image, high


def _show_bar(row, cmap: str, lo: float, hi: float, name: str) -> None:
    _, low, image, high = row
    image.update_image(o3d.geometry.Image(colorbar(cmap, 200, 12, vertical=False)))  # low values at the left
    low.text, high.text = f"{lo:.3g}", f"{hi:.3g} ({name})"


def _column(em: float) -> gui.Vert:
    return gui.Vert(0.25 * em, gui.Margins(0.5 * em, 0.25 * em, 0.5 * em, 0.25 * em))


class Panel:
    """A scene widget, the controls below it and its camera, in ``window`` (the :class:`viewer.app.Viewer`)."""

    name = ""

    def __init__(self, window):
        self.w = window
        self.widget = gui.SceneWidget()
        self.widget.scene = rendering.Open3DScene(window.window.renderer)
        self.controls = self._controls(window.em)
        self.pose: CameraPose | None = None
        self.fitted = False  # whether the pose was fitted to the panel's real shape

    @property
    def scene(self) -> rendering.Open3DScene:
        return self.widget.scene

    # -- what each panel shows ------------------------------------------------------------------------
    def _controls(self, em: float) -> gui.Widget:
        raise NotImplementedError

    def show(self, run: RunData) -> None:
        """The run's geometry that stays while the controls change (after start-up and every load)."""
        raise NotImplementedError

    def sync(self) -> None:
        """The controls' limits and values from the run and the view state."""

    def draw(self) -> None:
        raise NotImplementedError

    def subject_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The box the panel keeps in view."""
        return scene_box(self.w.run)

    def _fit(self, aspect: float) -> CameraPose:
        return frame_box(*scene_box(self.w.run), aspect)

    # -- the camera ------------------------------------------------------------------------------------
    def aspect(self) -> float:
        f = self.widget.frame
        return f.width / max(f.height, 1) if f.width > 0 else 1.0

    def camera(self) -> CameraPose:
        """The panel's pose, fitted to its subject the first time."""
        if self.pose is None:
            self.pose = self._fit(self.aspect())
            self.fitted = self.widget.frame.width > 0
            self.place(self.pose)
        return self.pose

    def place(self, pose: CameraPose) -> None:
        """The camera at ``pose``, with the widget's rotation centre at the pose's centre and its clipping
        planes from the panel's subject, so that dragging turns the subject about its middle."""
        lo, hi = self.subject_box()
        lo, hi = np.minimum(lo, pose.center), np.maximum(hi, pose.center)
        self.widget.setup_camera(pose.fov, o3d.geometry.AxisAlignedBoundingBox(lo, hi),
                                 pose.center.astype(np.float32))
        self.widget.look_at(pose.center.astype(np.float32), pose.eye.astype(np.float32), pose.up.astype(np.float32))

    def set_pose(self, pose: CameraPose) -> None:
        """Look from ``pose`` (a saved view's), as if fitted."""
        self.pose, self.fitted = pose, True
        self.place(pose)
        self.widget.force_redraw()

    def reset(self) -> None:
        """The camera back to its fitted view."""
        self.pose = None
        self.camera()
        self.widget.force_redraw()

    def refit(self) -> None:
        """A camera fitted before the panel had a size, fitted again."""
        if self.pose is not None and not self.fitted:
            self.pose = None
            self.camera()

    def fitted_distance(self) -> float:
        pose = self.camera()
        return float(np.linalg.norm(pose.eye - pose.center))

    def current_pose(self) -> CameraPose:
        """The camera as the user left it; the centre is on the view axis at the fitted distance."""
        cam = self.scene.camera
        M = np.asarray(cam.get_model_matrix(), np.float64)
        eye, forward, up = M[:3, 3], -M[:3, 2], M[:3, 1]
        return CameraPose(eye + self.fitted_distance() * forward, eye, up, float(cam.get_field_of_view()))

    def look_along(self, forward: np.ndarray, up: np.ndarray) -> None:
        """Look along ``forward`` at the panel's own subject, from its fitted distance."""
        center = self.camera().center
        forward = forward / max(np.linalg.norm(forward), view_tol.direction)
        eye = center - self.fitted_distance() * forward
        self.widget.look_at(center.astype(np.float32), eye.astype(np.float32), np.asarray(up, np.float32))
        self.widget.force_redraw()


class MaterialPanel(Panel):
    """Material space: a slice of a field with its colour bar, the fracture surfaces, B see-through."""

    name = "material"

    def _controls(self, em: float) -> gui.Widget:
        v = _column(em)
        row = gui.Horiz(0.5 * em)
        self.field_box = combobox(FIELDS, self.set_field)
        self.axis_box = combobox("xyz", self.set_axis)
        for w in (gui.Label("field"), self.field_box, gui.Label("axis"), self.axis_box):
            row.add_child(w)
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
        self.bar = _bar_row(em)
        v.add_child(self.bar[0])
        return v

    def show(self, run: RunData) -> None:
        show_material(self.scene, run)

    def sync(self) -> None:
        run, view = self.w.run, self.w.view
        self.level_slider.set_limits(0, max(run.pyramid_levels - 1, 0))
        self.offset_slider.double_value = view.offset
        self.level_slider.int_value = view.level
        self.field_box.selected_index = FIELDS.index(view.field)
        self.axis_box.selected_index = "xyz".index(view.axis)
        self.cutaway_box.checked = view.cutaway

    def _fit(self, aspect: float) -> CameraPose:
        return slice_pose(self.w.run, self.w.view, aspect)

    def draw(self) -> None:
        view = self.w.view
        lo, hi = set_slice(self.scene, self.w.run, view)
        set_cutaway(self.scene, self.w.run, view)
        _show_bar(self.bar, FIELD_CMAPS[view.field], lo, hi, view.field)
        self.camera()
        self.widget.force_redraw()

    def set_field(self, name: str) -> None:
        self.w.view = replace(self.w.view, field=name)
        self.draw()

    def set_cutaway(self, on: bool) -> None:
        self.w.view = replace(self.w.view, cutaway=bool(on))
        self.cutaway_box.checked = bool(on)
        self.draw()

    def set_axis(self, axis: str) -> None:
        self.w.view = replace(self.w.view, axis=axis)
        self.pose = None  # the slice turned: its camera too
        self.draw()

    def set_offset(self, offset: float) -> None:
        self.w.view = replace(self.w.view, offset=float(np.clip(offset, 0.0, 1.0)))
        self.offset_slider.double_value = self.w.view.offset
        self.draw()

    def set_level(self, level: int) -> None:
        self.w.view = replace(self.w.view, level=int(np.clip(level, 0, self.w.run.pyramid_levels - 1)))
        self.level_slider.int_value = self.w.view.level
        self.draw()


class _Player(Panel):
    """A panel that plays: its steps shown one after the other on the window's clock (``play_button`` is its
    control)."""

    def __init__(self, window):
        super().__init__(window)
        self.playing = False

    def toggle_play(self) -> None:
        self.playing = not self.playing
        self.play_button.text = "pause" if self.playing else "play"

    def step(self, by: int = 1) -> None:
        raise NotImplementedError


class IterationsPanel(_Player):
    """The fracture surface at an iteration (or a re-run's latest), coloured by psi or speed."""

    name = "iterations"

    def _controls(self, em: float) -> gui.Widget:
        v = _column(em)
        row = gui.Horiz(0.5 * em)
        self.slider = gui.Slider(gui.Slider.INT)
        self.slider.set_on_value_changed(lambda x: self.set_iteration(int(x)))
        row.add_child(self.slider)
        v.add_child(row)
        row = gui.Horiz(0.5 * em)
        for text, step in (("<", -1), (">", 1)):
            b = gui.Button(text)
            b.set_on_clicked(lambda s=step: self.set_iteration(self.w.view.iteration + s))
            row.add_child(b)
        self.play_button = gui.Button("play")
        self.play_button.set_on_clicked(self.toggle_play)
        row.add_child(self.play_button)
        row.add_child(gui.Label("colour"))
        self.color_box = combobox(COLOR_BY, self.set_color_by)
        row.add_child(self.color_box)
        v.add_child(row)
        self.bar = _bar_row(em)
        v.add_child(self.bar[0])
        self.label = gui.Label("")
        v.add_child(self.label)
        return v

    def show(self, run: RunData) -> None:
        show_context(self.scene, run)

    @property
    def count(self) -> int:
        return len(self.w.run.iterations) if self.w.run.has_iterations else 1

    def sync(self) -> None:
        self.slider.set_limits(0, max(self.count - 1, 0))
        self.slider.int_value = self.w.view.iteration
        self.color_box.selected_index = COLOR_BY.index(self.w.view.color_by)

    def subject_box(self) -> tuple[np.ndarray, np.ndarray]:
        return iteration_box(self.w.run) if self.w.run.has_iterations else scene_box(self.w.run)

    def _fit(self, aspect: float) -> CameraPose:
        return iteration_pose(self.w.run, aspect) if self.w.run.has_iterations else super()._fit(aspect)

    @property
    def color_range(self) -> tuple[float, float] | None:
        """The colour range of every iteration of the run (None without iterations)."""
        run = self.w.run
        return run.surface_range(self.w.view.color_by) if run.has_iterations else None

    def draw(self, live: dict | None = None) -> None:
        run, view = self.w.run, self.w.view
        if live is not None:  # a re-run in progress: its latest iteration
            c = live[view.color_by]
            rng = self.color_range or (float(c.min()), float(c.max()))
            surface = Surface(live["positions"], live["faces"], {k: live[k] for k in COLOR_BY})
            set_surface(self.scene, surface, view.color_by, rng)
            self.label.text = (f"re-run: iteration {live['iteration']}, {len(live['faces'])} triangles, "
                               f"E = {live['energy']:.4g}")
        elif run.has_iterations:
            set_surface(self.scene, run.iteration(view.iteration), view.color_by, self.color_range)
            _show_bar(self.bar, SURFACE_CMAPS[view.color_by], *self.color_range, view.color_by)
            self.label.text = iteration_caption(run, view.iteration)
        else:
            self.label.text = "no iterations in this run (refine.snapshots: false, or stopped early)"
        self.camera()
        self.widget.force_redraw()

    def set_iteration(self, k: int) -> None:
        if not self.w.run.has_iterations:
            return
        k = int(np.clip(k, 0, len(self.w.run.iterations) - 1))
        self.w.view = replace(self.w.view, iteration=k)
        self.slider.int_value = k
        self.draw()

    def set_color_by(self, name: str) -> None:
        self.w.view = replace(self.w.view, color_by=name)
        self.draw()

    def step(self, by: int = 1) -> None:
        """The next iteration (by ``by``), from the last back to the first while playing."""
        if self.w.run.has_iterations:
            self.set_iteration((self.w.view.iteration + by) % len(self.w.run.iterations))


class AnimationPanel(_Player):
    """The high-resolution pieces at a frame, the coarse ones see-through on request; the cameras' shared
    controls."""

    name = "animation"

    def _controls(self, em: float) -> gui.Widget:
        v = _column(em)
        self.slider = gui.Slider(gui.Slider.INT)
        self.slider.set_on_value_changed(lambda x: self.set_frame(int(x) - 1))
        v.add_child(self.slider)
        row = gui.Horiz(0.5 * em)
        self.play_button = gui.Button("play")
        self.play_button.set_on_clicked(self.toggle_play)
        row.add_child(self.play_button)
        self.overlay_box = gui.Checkbox("coarse overlay")
        self.overlay_box.set_on_checked(self.set_overlay)
        row.add_child(self.overlay_box)
        self.link_box = gui.Checkbox("link cameras")
        row.add_child(self.link_box)
        v.add_child(row)
        row = gui.Horiz(0.5 * em)
        b = gui.Button("reset view")
        b.set_on_clicked(lambda: self.w.reset_view())
        row.add_child(b)
        row.add_child(gui.Label("view"))
        self.preset_box = combobox(PRESETS, self.w.set_preset)
        row.add_child(self.preset_box)
        v.add_child(row)
        self.label = gui.Label("")
        v.add_child(self.label)
        return v

    # the ground's axis and height (show_stage's), and whether it is shown
    ground: tuple[int, float] | None = None
    ground_shown = True

    def show(self, run: RunData) -> None:
        show_stage(self.scene, run)
        up = "xyz".index(run.up_axis)
        self.ground, self.ground_shown = (up, ground_height(*animation_box(run), up)), True

    def ground_from_camera(self) -> bool:
        """The ground shown only while the camera is above it (seen from below it would hide the
        pieces: an orbit that passes under them would show a grey panel); True when that changed."""
        if self.ground is None:
            return False
        up, height = self.ground
        above = float(np.asarray(self.scene.camera.get_model_matrix())[up, 3]) >= height
        if above == self.ground_shown:
            return False
        self.scene.show_geometry("ground", above)
        self.ground_shown = above
        return True

    def sync(self) -> None:
        self.slider.set_limits(1, max(self.w.run.n_frames, 1))
        self.slider.int_value = self.w.view.frame + 1
        self.overlay_box.checked = self.w.view.overlay_coarse

    def subject_box(self) -> tuple[np.ndarray, np.ndarray]:
        return animation_box(self.w.run) if self.w.run.has_animation else scene_box(self.w.run)

    def _fit(self, aspect: float) -> CameraPose:
        return animation_pose(self.w.run, aspect) if self.w.run.has_animation else super()._fit(aspect)

    def draw(self) -> None:
        run = self.w.run
        if run.has_animation:
            set_frame(self.scene, run, self.w.view)
            self.label.text = f"frame {self.w.view.frame + 1} / {run.n_frames}, {len(run.piece_faces)} pieces"
        else:
            self.label.text = "no animation in this run (stopped before the animate stage)"
        self.camera()
        self.widget.force_redraw()

    def set_frame(self, t: int) -> None:
        if not self.w.run.has_animation:
            return
        t = int(np.clip(t, 0, self.w.run.n_frames - 1))
        self.w.view = replace(self.w.view, frame=t)
        self.slider.int_value = t + 1
        self.draw()

    def set_overlay(self, on: bool) -> None:
        self.w.view = replace(self.w.view, overlay_coarse=bool(on))
        self.overlay_box.checked = bool(on)
        self.draw()

    def step(self, by: int = 1) -> None:
        """The next frame (by ``by``), from the last back to the first while playing."""
        if self.w.run.has_animation:
            self.set_frame((self.w.view.frame + by) % self.w.run.n_frames)


__all__ = ["AnimationPanel", "IterationsPanel", "MaterialPanel", "Panel", "PRESETS", "combobox"]

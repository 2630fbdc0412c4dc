"""The window's exports: screenshots and videos of its panels, exactly the size asked for.

A figure is a panel's picture, from the panel's own camera (put back exactly
as it was afterwards: the window does not change), with the colour bar and
the caption in strips beside it (:mod:`viewer.annotate`), supersampled and on
a transparent background as the side panel's export settings say. Screenshots
are one panel, all three side by side, or the coarse and the refined pieces
side by side; videos step the iterations or the animation, one image per
window tick, so the window stays live while they are made. Files are numbered
(``screenshot_all_panels_001.png``, ...; never over an earlier one) and
written atomically into the run's ``renders/``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from open3d.visualization import rendering

from fracture.errors import InputError
from fracture.io.atomic import atomic_write_bytes, png_bytes
from viewer import annotate
from viewer.annotate import Bar
from viewer.looks import FIELD_CMAPS, SURFACE_CMAPS, capture, pieces_caption, set_frustum, show_pieces, slice_title
from viewer.media import Video, check_size, frame_counts
from viewer.state import PANELS


def numbered(folder: Path, stem: str, suffix: str) -> Path:
    """``folder/stem_NNN.suffix`` with the first number not taken: exports never overwrite."""
    taken = {p.name for p in folder.glob(f"{stem}_*{suffix}")} if folder.is_dir() else set()
    k = 1
    while f"{stem}_{k:03d}{suffix}" in taken:
        k += 1
    return folder / f"{stem}_{k:03d}{suffix}"


class Exports:
    """The exports of a window (:class:`viewer.app.Viewer`: its panels, cameras, view and export settings)."""

    def __init__(self, window):
        self.w = window

    def _export_size(self) -> tuple[int, int]:
        w, h = int(self.w.side.export_w.int_value), int(self.w.side.export_h.int_value)
        check_size(w, h, "export")
        k = int(self.w.side.export_scale.int_value)
        if max(w, h) * k > 8192:
            raise InputError(f"export: {w}x{h} supersampled {k} times is over 8192 pixels; expected a smaller "
                             "size or less supersampling")
        return w, h

    def _labels(self, i: int) -> tuple[Bar | None, str | None]:
        """Panel ``i``'s colour bar and caption in a figure."""
        v = self.w.view
        if i == 0:
            return Bar(FIELD_CMAPS[v.field], *self.w.run.field_range(v.field, v.level), v.field), slice_title(v)
        if i == 1 and self.w.iterations.color_range is not None:
            return (Bar(SURFACE_CMAPS[v.color_by], *self.w.iterations.color_range, v.color_by),
                    self.w.iterations.label.text)
        return None, self.w.animation.label.text

    def _picture(self, i: int, width: int, height: int, picture: tuple[int, int],
                 transparent: bool | None = None) -> np.ndarray:
        """Panel ``i`` from its current camera, at ``width x height`` with the panel's view over the
        upper-left ``picture`` part (supersampled and matted as the export settings say). The panel's
        camera is put back exactly as it was (the window is unchanged)."""
        k = int(self.w.side.export_scale.int_value)
        transparent = self.w.side.transparent_box.checked if transparent is None else transparent
        sw = self.w.panels[i].widget
        cam = sw.scene.camera
        current = self.w.panels[i].current_pose()
        near, far = cam.get_near(), cam.get_far()
        # keep all that the panel shows: a narrower picture gets a taller field of view
        f = sw.frame
        panel_aspect, aspect = f.width / max(f.height, 1), picture[0] / picture[1]
        half = np.arctan(np.tan(np.radians(current.fov) / 2) * panel_aspect / aspect)
        fov = max(current.fov, float(np.degrees(2 * half)))
        set_frustum(cam, fov, width * k, height * k, (picture[0] * k, picture[1] * k), near, far)

        def shot():
            return np.asarray(self.w.app.render_to_image(sw.scene, width * k, height * k))[..., :3]
        try:
            return capture(sw.scene, shot, k, transparent)
        finally:
            cam.set_projection(current.fov, panel_aspect, near, far, rendering.Camera.FovType.Vertical)
            sw.force_redraw()

    def panel_image(self, i: int, width: int, height: int, caption: str | None = None,
                    transparent: bool | None = None) -> np.ndarray:
        """Panel ``i`` as a ``width x height`` figure: its picture, its colour bar and its caption."""
        bar, text = self._labels(i)
        lay = annotate.layout(width, height, bar is not None, True)
        img = self._picture(i, width, height, lay.picture, transparent)
        return annotate.compose(img[:lay.picture[1], :lay.picture[0]], lay, bar, caption or text)

    def compare_image(self, width: int, height: int) -> np.ndarray:
        """The coarse pieces and the refined pieces at the shown frame, side by side, from the animation
        panel's camera."""
        if not self.w.run.has_animation:
            raise InputError("this run has no animation: the coarse and refined pieces are compared in it")
        scene, t = self.w.animation.scene, self.w.view.frame
        coarse, refined = self.w.run.coarse_pieces(t), self.w.run.pieces_at(t)
        figures = []
        try:
            for name, pieces, half in (("coarse", coarse, width // 2), ("refined", refined, width - width // 2)):
                for c in range(max(len(coarse), len(refined))):
                    for n in (f"piece_{c}", f"piece_{c}_fracture"):
                        if scene.has_geometry(n):
                            scene.remove_geometry(n)
                show_pieces(scene, pieces)
                figures.append(self.panel_image(2, half, height, pieces_caption(name, pieces, t)))
        finally:
            self.w.animation.draw()
        return annotate.side_by_side(figures)

    def screenshot(self, which: str = "all panels", path: str | Path | None = None) -> Path | None:
        """A PNG of one panel (``material``, ``iterations``, ``animation``), of all three side by side,
        or of the coarse and refined pieces side by side (``coarse vs refined``)."""
        try:
            w, h = self._export_size()
            if which == "all panels":
                widths = [w // 3 // 2 * 2] * 2
                widths.append(w - sum(widths))
                img = np.concatenate([self.panel_image(i, pw, h) for i, pw in enumerate(widths)], axis=1)
            elif which == "coarse vs refined":
                img = self.compare_image(w, h)
            else:
                img = self.panel_image(PANELS.index(which), w, h)
            stem = f"screenshot_{which.replace(' ', '_')}"
            path = Path(path) if path else numbered(self.w.run.dir / "renders", stem, ".png")
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_bytes(path, png_bytes(img))
        except (InputError, OSError, ValueError) as exc:
            self.w.report_error("screenshot failed", exc)
            return None
        self.w.say(f"saved {path}")
        return path

    def export_video(self, what: str, path: str | Path | None = None) -> None:
        """An MP4 of the iterations or the animation, one image per window tick (the window stays live);
        each image is shown for the export's seconds per image, the last held for its hold seconds."""
        if self.w._job is not None:
            self.w.say("a video export is already going; wait for it to finish")
            return
        try:
            w, h = self._export_size()
            fps = int(self.w.side.export_fps.int_value)
            if what == "iterations" and not self.w.run.has_iterations or what == "animation" and not self.w.run.has_animation:
                raise InputError(f"this run has no {what} to export")
            n = len(self.w.run.iterations) if what == "iterations" else self.w.run.n_frames
            # the animation at its own frame rate; iterations at the chosen seconds per image
            seconds = (float(self.w.side.export_seconds.double_value) if what == "iterations"
                       else self.w.run.seconds_per_frame)
            counts = frame_counts(n, seconds, fps)
            counts[-1] += round(float(self.w.side.export_hold.double_value) * fps)
            path = Path(path) if path else numbered(self.w.run.dir / "renders", f"window_{what}", ".mp4")
            path.parent.mkdir(parents=True, exist_ok=True)
            video = Video(path, w, h, fps)
        except (InputError, OSError) as exc:
            self.w.report_error("video export failed", exc)
            return
        i = 1 if what == "iterations" else 2
        keep = self.w.view

        def job():
            try:
                for k in range(n):
                    if what == "iterations":
                        self.w.iterations.set_iteration(k)
                    else:
                        self.w.animation.set_frame(k)
                    img = self.panel_image(i, w, h, transparent=False)
                    for _ in range(counts[k]):
                        video.add(img)
                    self.w.say(f"video: {k + 1} / {n}")
                    yield
            except BaseException:
                video.abort()
                raise
            else:
                video.close()
                self.w.say(f"saved {path}")
            finally:  # the panel and its slider back where they were
                if what == "iterations":
                    self.w.iterations.set_iteration(keep.iteration)
                else:
                    self.w.animation.set_frame(keep.frame)

        self.w._job = job()

"""Headless figures and videos of a run: ``fracref render RUN_DIR --what slices|iterations|animation``.

Open3D's OffscreenRenderer draws the same scenes as the window (see
:mod:`viewer.looks`) through EGL with no display. Every image is written
atomically, the video to a temporary file first: an interrupted render
never leaves a half-written file under a final name.

* ``slices``: the material-space panel at a few offsets along the chosen
  axis (PNG each, with a colour bar) and an MP4 sweeping through them;
* ``iterations``: the fracture surface at every stored iteration (PNG each,
  with a colour bar and the iteration, triangle count and energy) and an MP4;
* ``animation``: the pieces at every frame (PNG each) and an MP4.
"""

from __future__ import annotations

import os

# Open3D 0.19 needs EGL's surfaceless platform to render with no X display;
# it must be in the environment before the first renderer is made.
if not os.environ.get("DISPLAY"):
    os.environ.setdefault("EGL_PLATFORM", "surfaceless")

from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from fracture.atomic import atomic_write_bytes, png_bytes  # noqa: E402
from fracture.errors import InputError  # noqa: E402
from viewer import annotate  # noqa: E402
from viewer.data import RunData  # noqa: E402
from viewer.media import Video, check_size  # noqa: E402
from viewer.looks import (  # noqa: E402
    FIELD_CMAPS, SURFACE_CMAPS, View, animation_pose, apply_camera, iteration_caption, iteration_pose,
    prepare, set_frame, set_slice, set_surface, show_context, show_material, slice_pose, slice_title,
)

WHAT = ("slices", "iterations", "animation")
# Views with a colour bar frame their content in this share of the width (the bar is at the right).
BAR_ROOM = 0.8


class Renderer:
    """One offscreen renderer of a fixed size, reused for every image."""

    def __init__(self, width: int, height: int):
        from open3d.visualization import rendering

        self.width, self.height = width, height
        self.r = rendering.OffscreenRenderer(width, height)
        self.r.scene.view.set_post_processing(True)

    @property
    def scene(self):
        return self.r.scene

    def image(self, pose) -> np.ndarray:
        apply_camera(self.r.scene.camera, pose, self.width, self.height)
        return np.asarray(self.r.render_to_image())[..., :3].copy()


def _progress(total: int, desc: str, quiet: bool):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, disable=quiet, leave=False)


def _write_sequence(images, out: Path, stem: str, width: int, height: int, fps: int, total: int,
                    quiet: bool) -> list[Path]:
    """PNG per image (``stem_NNNN.png``) and ``stem.mp4``; returns the files written."""
    out.mkdir(parents=True, exist_ok=True)
    video = Video(out / f"{stem}.mp4", width, height, fps)
    written = []
    try:
        with _progress(total, stem, quiet) as bar:
            for i, img in enumerate(images):
                p = out / f"{stem}_{i:04d}.png"
                atomic_write_bytes(p, png_bytes(img))
                written.append(p)
                video.add(img)
                bar.update()
    except BaseException:
        video.abort()
        raise
    video.close()
    return written + [video.path]


def slice_images(run: RunData, view: View, renderer: Renderer, offsets):
    pose = slice_pose(run, view, BAR_ROOM * renderer.width / renderer.height)
    show_material(renderer.scene, run)
    for off in offsets:
        v = replace(view, offset=float(off))
        rng = set_slice(renderer.scene, run, v)
        yield annotate.with_colorbar(renderer.image(pose), FIELD_CMAPS[v.field], rng, slice_title(v))


def iteration_images(run: RunData, view: View, renderer: Renderer):
    pose = iteration_pose(run, BAR_ROOM * renderer.width / renderer.height)
    rng = run.surface_range(view.color_by)
    show_context(renderer.scene, run)
    for k in range(len(run.iterations)):
        set_surface(renderer.scene, run.iteration(k), view.color_by, rng)
        yield annotate.with_colorbar(renderer.image(pose), SURFACE_CMAPS[view.color_by], rng, view.color_by,
                                     iteration_caption(run, k))


def render(run_dir: str | Path, what: str | tuple[str, ...] = WHAT, out: str | Path | None = None,
           width: int = 1280, height: int = 720, fps: int = 10, view: View | None = None,
           quiet: bool = False) -> dict[str, list[Path]]:
    """Render PNGs and an MP4 of each view ``what`` of a run into ``out`` (default ``RUN_DIR/renders``),
    reading the run and making the renderer once.

    Returns the files written, per view.
    """
    whats = (what,) if isinstance(what, str) else tuple(what)
    for w in whats:
        if w not in WHAT:
            raise InputError(f"--what must be one of {', '.join(WHAT)}, got {w!r}")
    check_size(width, height)
    run = RunData(run_dir)
    view = (view or View()).check(run)
    out = Path(out) if out is not None else run.dir / "renders"
    renderer = Renderer(width, height)
    return {w: _render_one(run, w, view, renderer, out, fps, quiet) for w in whats}


def _render_one(run: RunData, what: str, view: View, renderer: Renderer, out: Path, fps: int,
                quiet: bool) -> list[Path]:
    width, height = renderer.width, renderer.height
    if what == "slices":
        offsets = np.linspace(0.1, 0.9, 9)
        return _write_sequence(slice_images(run, view, renderer, offsets), out, f"slices_{view.field}_{view.axis}",
                               width, height, fps, len(offsets), quiet)
    if what == "iterations":
        if not run.has_iterations:
            raise InputError(f"{run.dir}: no iterations to render (run the refine stage with refine.snapshots: true)")
        return _write_sequence(iteration_images(run, view, renderer), out, f"iterations_{view.color_by}",
                               width, height, fps, len(run.iterations), quiet)
    if not run.has_animation:
        raise InputError(f"{run.dir}: no animation to render (the run stopped before the animate stage)")
    pose = animation_pose(run, width / height)
    n = run.n_frames
    prepare(renderer.scene)

    def frames():
        for t in range(n):
            set_frame(renderer.scene, run, replace(view, frame=t))
            yield annotate.caption(renderer.image(pose), f"frame {t + 1} / {n}")
    return _write_sequence(frames(), out, "animation", width, height, fps, n, quiet)

"""Headless figures and videos of a run: ``fracref render RUN_DIR --what slices|iterations|animation|compare|turntable``.

Open3D's OffscreenRenderer draws the same scenes as the window (see
:mod:`viewer.looks`) through EGL with no display. Every image is written
atomically, the video to a temporary file first: an interrupted render
never leaves a half-written file under a final name.

* ``slices``: the material-space panel at a few offsets along the chosen
  axis (PNG each, with a colour bar) and an MP4 sweeping through them;
* ``iterations``: the fracture surface at every stored iteration (PNG each,
  with a colour bar and the iteration, triangle count and energy) and an MP4;
* ``animation``: the pieces at every frame over a ground with their shadows (PNG each) and an MP4;
* ``compare``: the coarse and the refined pieces side by side at one frame, one camera (PNG);
* ``turntable``: one turn of the camera around the refined pieces at one frame (MP4).

Figures can be supersampled (rendered ``k`` times larger and averaged down) and
written with a transparent background (PNG; the videos are composited on white).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from fracture.io.atomic import atomic_write_bytes, png_bytes
from fracture.errors import InputError
from viewer import annotate
from viewer.annotate import Bar
from viewer.data import RunData, Surface
from viewer.request import check_request, check_supersample
from viewer.media import Timing, Video
from viewer.looks import (
    FIELD_CMAPS, SURFACE_CMAPS, CameraPose, View, animation_pose, apply_camera, capture, dominant_normal, frame_points,
    iteration_caption, scene_box,
    iteration_pose, pieces_caption, set_cutaway, set_frame, set_slice, set_surface, show_context, show_material, show_pieces,
    show_stage, slice_pose, slice_title, spread, turntable_poses,
)


@contextlib.contextmanager
def _silent(quiet: bool):
    """With ``quiet``, the process's stdout and stderr (file descriptors 1 and 2, where C++ libraries write)
    sent to the null device for the block, and restored after it."""
    if not quiet:
        yield
        return
    sys.stdout.flush()
    sys.stderr.flush()
    kept = [os.dup(1), os.dup(2)]
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(kept[0], 1)
        os.dup2(kept[1], 2)
        for fd in kept + [null]:
            os.close(fd)


class Renderer:
    """One offscreen renderer of the figure's size (times the supersampling), reused for every image."""

    def __init__(self, width: int, height: int, supersample: int = 1, transparent: bool = False,
                 quiet: bool = False):
        from open3d.visualization import rendering

        check_supersample(width, height, supersample)
        self.width, self.height, self.k, self.transparent = width, height, int(supersample), transparent
        # Open3D 0.19 renders with no X display only on EGL's surfaceless platform, which must be in the
        # environment before its first offscreen renderer is made (here: a renderer is what needs it)
        if not os.environ.get("DISPLAY"):
            os.environ.setdefault("EGL_PLATFORM", "surfaceless")
        with _silent(quiet):  # Filament's greetings (EGL, OpenGL versions) go to the process's own stdout
            self.r = rendering.OffscreenRenderer(width * self.k, height * self.k)
        self.r.scene.view.set_post_processing(True)

    @property
    def scene(self):
        return self.r.scene

    def _shot(self) -> np.ndarray:
        return np.asarray(self.r.render_to_image())[..., :3]

    def image(self, pose: CameraPose, picture: tuple[int, int] | None = None) -> np.ndarray:
        """The scene from ``pose`` at the figure's size (RGBA when transparent), the pose's view
        filling the upper-left ``picture`` (default: all of it)."""
        k = self.k
        pic = (picture[0] * k, picture[1] * k) if picture is not None else None
        apply_camera(self.r.scene.camera, pose, self.width * k, self.height * k, pic)
        return capture(self.scene, self._shot, k, self.transparent)

    def figure(self, pose: CameraPose, bar: Bar | None = None, caption: str | None = None,
               width: int | None = None) -> np.ndarray:
        """A figure ``width`` wide (default: the renderer's): the picture from ``pose`` with its colour
        bar strip and caption strip."""
        lay = annotate.layout(width or self.width, self.height, bar is not None, caption is not None)
        img = self.image(pose, lay.picture)
        pw, ph = lay.picture
        return annotate.compose(img[:ph, :pw], lay, bar, caption)

    def picture_aspect(self, bar: bool, caption: bool, width: int | None = None) -> float:
        w, h = annotate.layout(width or self.width, self.height, bar, caption).picture
        return w / h


def _progress(total: int, desc: str, quiet: bool):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, disable=quiet, unit="image")


def _write_sequence(images, out: Path, stem: str, width: int, height: int, timing: Timing, pace: float,
                    total: int, quiet: bool, pngs: bool = True) -> list[Path]:
    """PNG per image (``stem_NNNN.png``, unless ``pngs`` is off) and ``stem.mp4``, each image shown for
    the timing's seconds (``pace`` by default); returns the files written.

    Everything is written into a staging folder first and moved into ``out`` once complete, replacing
    that sequence's files of an earlier render (and only them): an interrupted render leaves ``out``
    as it was.
    """
    out.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{stem}.partial-", dir=out))
    try:
        counts = timing.counts(total, pace)
        video, written = None, []
        try:
            with _progress(total, stem, quiet) as bar:
                for i, img in enumerate(images):
                    if video is None:  # begun with the first image: a run's file that cannot be read stops
                        video = Video(stage / f"{stem}.mp4", width, height, timing.fps)  # it before any
                    if pngs:
                        p = stage / f"{stem}_{i:04d}.png"
                        p.write_bytes(png_bytes(img))
                        written.append(p)
                    frame = annotate.over_white(img)
                    for _ in range(counts[i]):
                        video.add(frame)
                    bar.update()
        except BaseException:
            if video is not None:
                video.abort()
            raise
        if video is None:
            raise ValueError(f"no images to write for {stem}")
        video.close()
        return _publish(stage, out, stem, written + [video.path])
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _publish(stage: Path, out: Path, stem: str, files: list[Path]) -> list[Path]:
    """Move a finished sequence's ``files`` from ``stage`` into ``out``; files of an earlier render of
    the same sequence that this one does not have (more iterations, say) are removed."""
    names = {f.name for f in files}
    for old in list(out.glob(f"{stem}_[0-9][0-9][0-9][0-9].png")) + [out / f"{stem}.mp4"]:
        if old.name not in names:
            old.unlink(missing_ok=True)
    moved = []
    for f in files:
        os.replace(f, out / f.name)
        moved.append(out / f.name)
    return moved


def slice_images(run: RunData, view: View, renderer: Renderer, offsets, pose: CameraPose | None = None):
    pose = pose or slice_pose(run, view, renderer.picture_aspect(True, True))
    show_material(renderer.scene, run)
    for off in offsets:
        v = replace(view, offset=float(off))
        lo, hi = set_slice(renderer.scene, run, v)
        set_cutaway(renderer.scene, run, v)
        yield renderer.figure(pose, Bar(FIELD_CMAPS[v.field], lo, hi, v.field), slice_title(v))


def iteration_images(run: RunData, view: View, renderer: Renderer, pose: CameraPose | None = None):
    pose = pose or iteration_pose(run, renderer.picture_aspect(True, True))
    lo, hi = run.surface_range(view.color_by)
    show_context(renderer.scene, run)
    for k in range(len(run.iterations)):
        set_surface(renderer.scene, run.iteration(k), view.color_by, (lo, hi))
        yield renderer.figure(pose, Bar(SURFACE_CMAPS[view.color_by], lo, hi, view.color_by),
                              iteration_caption(run, k))


def animation_images(run: RunData, view: View, renderer: Renderer, pose: CameraPose | None = None):
    pose = pose or animation_pose(run, renderer.picture_aspect(False, True))
    show_stage(renderer.scene, run)
    n = run.n_frames
    for t in range(n):
        set_frame(renderer.scene, run, replace(view, frame=t))
        yield renderer.figure(pose, caption=f"frame {t + 1} / {n}")


def compare_image(run: RunData, t: int, renderer: Renderer, pose: CameraPose | None = None) -> np.ndarray:
    """The coarse pieces and the refined pieces at frame ``t``, side by side, one camera, each half
    of the renderer's width."""
    coarse, refined = run.coarse_pieces(t), run.pieces_at(t)
    P = np.concatenate([spread(p.V, 2000) for p in coarse + refined])
    widths = (renderer.width // 2, renderer.width - renderer.width // 2)
    pose = pose or animation_pose(run, renderer.picture_aspect(False, True, widths[0]), P)
    halves = []
    for name, pieces, half in (("coarse", coarse, widths[0]), ("refined", refined, widths[1])):
        show_stage(renderer.scene, run)
        show_pieces(renderer.scene, pieces)
        halves.append(renderer.figure(pose, caption=pieces_caption(name, pieces, t), width=half))
    return annotate.side_by_side(halves)


def contact_sheet(run_dirs: list[Path], captions: list[str], out: str | Path, tile: tuple[int, int] = (480, 360),
                  columns: int | None = None) -> Path:
    """One PNG of the runs' refined fracture surfaces in a grid of tiles, each with its caption and a colour
    bar, coloured by the material strength zeta under them (what the runs share, whatever their psi) on one
    range, all from one camera (facing the first surface, fitted to every one). Written atomically."""
    from fields.interpolate import trilinear

    runs = [RunData(d) for d in run_dirs]
    if not runs:
        raise InputError("contact sheet: no finished runs to show")
    surfaces = []
    for r in runs:
        s = r.refined_fracture
        if s is None:
            raise InputError(f"{r.dir}: the contact sheet needs the refined fracture surface (the refine stage)")
        zeta = trilinear(r.grid, r.field("zeta"), np.asarray(s.V, np.float64))
        surfaces.append(Surface(s.V, s.F, {"zeta": zeta}))
    columns = columns or int(np.ceil(np.sqrt(len(runs))))
    renderer = Renderer(*tile)
    values = np.concatenate([s.scalars["zeta"] for s in surfaces])
    lo, hi = (float(v) for v in np.percentile(values, [1, 99]))
    hi = hi if hi > lo else lo + 1.0
    aspect = renderer.picture_aspect(True, True)
    blo, bhi = scene_box(runs[0])
    look = dominant_normal(np.asarray(surfaces[0].V, np.float64), surfaces[0].F)
    pose = frame_points(np.concatenate([spread(s.V, 3000) for s in surfaces]), aspect, look,
                        np.eye(3)[int(np.argsort(bhi - blo)[1])])
    tiles = []
    for r, surface, caption in zip(runs, surfaces, captions):
        show_context(renderer.scene, r)
        set_surface(renderer.scene, surface, "zeta", (lo, hi), FIELD_CMAPS["zeta"])
        tiles.append(renderer.figure(pose, Bar(FIELD_CMAPS["zeta"], lo, hi, "zeta"), caption))
    blank = np.full_like(tiles[0], 255)
    rows = [np.concatenate((tiles[i:i + columns] + [blank] * columns)[:columns], axis=1)
            for i in range(0, len(tiles), columns)]
    out = Path(out)
    atomic_write_bytes(out, png_bytes(np.concatenate(rows, axis=0)))
    return out


def render(run_dir: str | Path | RunData, what: str | tuple[str, ...] | None = None, out: str | Path | None = None,
           width: int = 1280, height: int = 720, timing: Timing | None = None, view: View | None = None,
           quiet: bool = False, supersample: int = 1, transparent: bool = False,
           turntable_seconds: float = 6.0, cameras: dict | None = None) -> dict[str, list[Path]]:
    """Render each view ``what`` of a run into ``out`` (default ``RUN_DIR/renders``): PNGs and an MP4
    (slices, iterations, animation), a PNG (compare) or an MP4 (turntable), reading the run and
    making the renderer once. ``what`` None: those of :data:`~viewer.request.DEFAULT_WHAT` the run has (:func:`~viewer.request.check_request` checks the request). ``cameras`` (per panel name, as in a view file)
    replace the fitted cameras: ``material`` for slices, ``iterations``, ``animation`` for the
    animation and the comparison.

    ``run_dir`` may be the run already read (a :class:`RunData`), so that what a caller checked is not
    read again. Returns the files written, per view.
    """
    run, whats, view, timing = check_request(run_dir, what, width, height, timing, view, turntable_seconds,
                                             supersample)
    out = Path(out) if out is not None else run.dir / "renders"
    made = [p for p in (out, *out.parents) if not p.exists()]  # the deepest first
    cameras = cameras or {}
    # one per process: Open3D's are not independent
    renderer = Renderer(width, height, supersample, transparent, quiet)
    done = {}
    try:
        for w in whats:
            if w == "compare":
                img = compare_image(run, view.frame, renderer, cameras.get("animation"))
                out.mkdir(parents=True, exist_ok=True)
                p = out / f"compare_frame_{view.frame + 1:04d}.png"
                atomic_write_bytes(p, png_bytes(img))
                done[w] = [p]
            else:
                done[w] = _render_one(run, w, view, renderer, out, timing, quiet, turntable_seconds, cameras)
    except BaseException:
        for p in made:  # the folders this render made and left empty go again
            try:
                p.rmdir()
            except OSError:
                break
        raise
    return done


def _render_one(run: RunData, what: str, view: View, renderer: Renderer, out: Path, timing: Timing,
                quiet: bool, turntable_seconds: float, cameras: dict) -> list[Path]:
    width, height = renderer.width, renderer.height
    if what == "slices":
        offsets = np.linspace(0.1, 0.9, 9)
        return _write_sequence(slice_images(run, view, renderer, offsets, cameras.get("material")), out, f"slices_{view.field}_{view.axis}",
                               width, height, timing, 0.4, len(offsets), quiet)
    if what == "iterations":
        return _write_sequence(iteration_images(run, view, renderer, cameras.get("iterations")), out, f"iterations_{view.color_by}",
                               width, height, timing, 0.25, len(run.iterations), quiet)
    if what == "animation":
        return _write_sequence(animation_images(run, view, renderer, cameras.get("animation")), out, "animation", width, height, timing,
                               run.seconds_per_frame, run.n_frames, quiet)
    # turntable: every video frame a new camera, the pieces still
    n = max(2, round(turntable_seconds * timing.fps))
    pieces = run.pieces_at(view.frame)
    show_stage(renderer.scene, run)
    show_pieces(renderer.scene, pieces)
    poses = turntable_poses(run, pieces, renderer.picture_aspect(False, True), n)
    caption = f"frame {view.frame + 1} / {run.n_frames}, {len(pieces)} pieces"
    images = (renderer.figure(p, caption=caption) for p in poses)
    return _write_sequence(images, out, f"turntable_frame_{view.frame + 1:04d}", width, height,
                           replace(timing, hold=0.0, image_seconds=None), 1.0 / timing.fps, n, quiet, pngs=False)

"""A render's request checked against its run before anything is drawn: what to render, the figure's
size, the videos' timing and the view (:func:`check_request`). Kept apart from :mod:`viewer.render` and
Open3D, so that ``fracref render`` says what is wrong with its flags or its run directory before the
renderer's libraries load (seconds of imports for a one-line answer)."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from fracture.errors import InputError
from viewer.data import RunData
from viewer.media import Timing, check_size
from viewer.view import View

WHAT = ("slices", "iterations", "animation", "compare", "turntable")
DEFAULT_WHAT = ("slices", "iterations", "animation")
MAX_SUPERSAMPLE = 4


class Request(NamedTuple):
    """A checked request: the run, what to render (those of :data:`DEFAULT_WHAT` the run has when none was
    asked for), the view with its iteration and frame resolved, and the videos' timing."""

    run: RunData
    whats: tuple[str, ...]
    view: View
    timing: Timing


def check_supersample(width: int, height: int, supersample: int) -> None:
    """Supersampling of 1..:data:`MAX_SUPERSAMPLE` times, within the renderer's 8192 pixels."""
    if not isinstance(supersample, (int, np.integer)) or not 1 <= supersample <= MAX_SUPERSAMPLE:
        raise InputError(f"supersample must be an integer in 1..{MAX_SUPERSAMPLE}, got {supersample!r}")
    if max(width, height) * supersample > 8192:
        raise InputError(f"{width}x{height} supersampled {supersample} times is over 8192 pixels; "
                         "expected a smaller size or less supersampling")


def check_request(run_dir: str | Path | RunData, what: str | tuple[str, ...] | None, width: int, height: int,
                  timing: Timing | None = None, view: View | None = None, turntable_seconds: float = 6.0,
                  supersample: int = 1) -> Request:
    """The request of :func:`viewer.render.render`, checked; an :class:`InputError` names the first value
    that is wrong (by its ``fracref render`` flag where it has one) and what is allowed."""
    whats = () if what is None else (what,) if isinstance(what, str) else tuple(what)
    for w in whats:
        if w not in WHAT:
            raise InputError(f"--what must be one of {', '.join(WHAT)}, got {w!r}")
    check_size(width, height)
    check_supersample(width, height, supersample)
    timing = (timing or Timing()).check()
    if not 0.5 <= turntable_seconds <= 600:
        raise InputError(f"turntable seconds must be in 0.5..600, got {turntable_seconds}")
    run = run_dir if isinstance(run_dir, RunData) else RunData(run_dir)
    if what is None:
        whats = available(run)
        if not whats:
            raise InputError(f"{run.dir}: nothing to render: the run stopped after its "
                             f"{_last_stage(run)} stage (the slices need the fields stage)")
    view = (view or View()).check(run)
    if "slices" in whats and not run.has_fields:
        raise InputError(f"{run.dir}: no fields to render slices of (the run stopped after its "
                         f"{_last_stage(run)} stage)")
    needs_animation = [w for w in whats if w in ("animation", "compare", "turntable")]
    if needs_animation and not run.has_animation:
        raise InputError(f"{run.dir}: no animation to render for {', '.join(needs_animation)} "
                         f"(the run stopped before the animate stage)")
    if "iterations" in whats and not run.has_iterations:
        raise InputError(f"{run.dir}: no iterations to render (run the refine stage with refine.snapshots: true)")
    if ({"compare", "turntable"} & set(whats) or run.has_animation) and not 0 <= view.frame < run.n_frames:
        raise InputError(f"frame must be in 1..{run.n_frames}, got {view.frame + 1}")
    return Request(run, whats, view, timing)


def available(run: RunData) -> tuple[str, ...]:
    """The views of :data:`DEFAULT_WHAT` a run has the outputs of (a run stopped early has fewer)."""
    has = {"slices": run.has_fields, "iterations": run.has_iterations, "animation": run.has_animation}
    return tuple(w for w in DEFAULT_WHAT if has[w])


def _last_stage(run: RunData) -> str:
    stages = list(run.manifest.get("stages", {}))
    return stages[-1] if stages else "first"

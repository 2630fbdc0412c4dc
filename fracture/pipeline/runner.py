"""The experiment runner: configured stages in order, one run directory.

:func:`run` executes the stages of :data:`fracture.pipeline.stages.STAGES` (an
explicit ordered tuple; a caller may pass its own) up to ``until`` inside a
staging directory, then writes ``config.yaml`` and ``manifest.json`` and moves
the directory into place (see :mod:`fracture.io.atomic`). Stages hand
in-memory results to later stages through ``RunContext.products`` (a
:class:`~fracture.pipeline.context.Products`) and write their files with the
``RunContext.save_*`` helpers, which record each file for the manifest.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import platform
import time
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from dataclasses import dataclass
from datetime import datetime, timezone
from functools import lru_cache
from importlib import metadata
from pathlib import Path
from typing import Any

from fracture.errors import JoinError, ResultError, StageError
from fracture.io import layout
from fracture.io.atomic import staged_directory
from fracture.pipeline.config import dump_config
from fracture.pipeline.context import RunContext
from fracture.pipeline.stages import STAGES, Stage

log = logging.getLogger(__name__)

# Distributions whose versions go into the manifest.
_PACKAGES = ("numpy", "scipy", "numba", "open3d", "pymeshlab", "libigl", "noise", "PyYAML", "imageio", "fracref")


def available_stages(stages: tuple[Stage, ...] = STAGES) -> list[str]:
    """The stages' names, in pipeline order."""
    return [s.name for s in stages]


def timing_table(manifest: dict) -> str:
    """Seconds per stage and in all, as a small table (printed at the end of a run)."""
    stages = manifest.get("stages", {})
    width = max([len(n) for n in stages] + [5])
    rows = [f"  {name:<{width}}  {info['seconds']:8.1f} s" for name, info in stages.items()]
    total = sum(info["seconds"] for info in stages.values())
    return "\n".join(["time per stage:", *rows, f"  {'total':<{width}}  {total:8.1f} s"])


def _searched(ctx: RunContext) -> bool:
    """The refined surface is the global search's, polished (not the coarse surface's)."""
    search = ctx.stats.get("refine", {}).get("search")
    return bool(search and search.get("replaced_coarse_surface")) and ctx.config.refine.search != "none"


@dataclass(frozen=True)
class _Before:
    """What a run's context held when a stage began: its notes and files (how many), counts and statistics."""

    notes: int
    files: int
    counts: dict
    stats: dict

    @classmethod
    def of(cls, ctx: RunContext) -> "_Before":
        return cls(len(ctx.notes), len(ctx.files), dict(ctx.counts), dict(ctx.stats))


# Refinements after the first whose surface yields no sound pieces: the flow alone (after a search), then
# other draws of the refinement's random choices.
_REDRAWS = 2


@dataclass(frozen=True)
class _Again:
    """How to refine again after a refusal: the refine keys changed, what the run says, and its note."""

    update: dict
    say: str
    note: str


def _again(ctx: RunContext, first_draw: int) -> _Again | None:
    """The next refinement to try after a later stage refused the refined surface (None: none is left).

    A searched surface is refined again with the flow alone first (the search's surface and the flow's
    differ most). Then the refinement runs again with other draws of its random choices (where edges and
    triangles are split, ``refine.draw``), up to :data:`_REDRAWS` more: the rare rims that cannot be cut
    into B (a sheet grazing a concave part of B, a rim doubling back in a groove of it) and pieces that do
    not close come from the fine detail of one refinement, and another draw makes other detail there (on a
    plank torus of the Blender sweeps, draw 1 of the one draw 0 refused)."""
    refine = ctx.config.refine
    if _searched(ctx):
        return _Again({"search": "none"}, "no sound pieces can be made of the global search's surface; refining "
                      "again with the flow alone", "the global search's surface was refused: {why}; refined again "
                      "with the flow alone (refine.search: none), from the coarse surface")
    if refine.draw < first_draw + _REDRAWS:
        draw = refine.draw + 1
        return _Again({"draw": draw}, f"no sound pieces can be made of the refined surface; refining again with "
                      f"other random split positions (refine.draw: {draw})", "the refined surface was refused: {why}; "
                      f"refined again with other random split positions (refine.draw: {draw})")
    return None


def _undo_refinement(ctx: RunContext, again: _Again, refused: JoinError | ResultError, manifest: dict,
                     before: _Before, refusals: list[str]) -> None:
    """Take the context back to what it held before the refinement (``before``: its notes, files, counts and
    statistics, and the cache keys from it on), with the refine keys ``again.update``, so that the next
    refinement (the run goes on from the refine stage) and its cache entry hold their own files and counts;
    the refused one's entry stays (it is what that config refines to). ``refusals`` and the notes gain the note
    of this refusal (``refused``: a stage could not join the refined surface to the object's surface, or a
    piece would not close or would cross itself)."""
    for info in manifest["stages"].values():  # their entries copy the files about to be removed
        if isinstance(info.get("cache"), Future):
            info["cache"] = _stored(info["cache"].result())
    ctx.wait_for_files()
    for rel in ctx.files[before.files:]:
        (ctx.dir / rel).unlink(missing_ok=True)
    del ctx.files[before.files:]
    why = refused.problem if isinstance(refused, JoinError) else str(refused).removeprefix("animate: ")
    refusals.append("refine: " + again.note.format(why=why))
    del ctx.notes[before.notes:]  # the earlier refusals' notes came before the refinement: they stay
    ctx.notes.append(refusals[-1])
    ctx.counts, ctx.stats = dict(before.counts), dict(before.stats)
    names = list(ctx.keys)
    for name in names[names.index("refine"):] if "refine" in names else ():
        del ctx.keys[name]  # the cache keys of the refinement and of the stages after it are made again
    cfg = ctx.config
    ctx.config = cfg.model_copy(update={"refine": cfg.refine.model_copy(update=again.update)})
    ctx.say(f"refine: {again.say}")


def _after_tries(refused: JoinError | ResultError, tries: int, draw: int) -> JoinError | ResultError:
    """``refused``, saying how often the run refined (``tries``, the last with ``refine.draw`` ``draw``) when it
    refined more than once."""
    if tries == 1:
        return refused
    told = f" (the surfaces of {tries} refinements were refused, the last with refine.draw: {draw})"
    if isinstance(refused, JoinError):
        head = f"{refused.where}: {refused.problem}"
        return JoinError(refused.where, refused.problem, str(refused).removeprefix(head) + told)
    return ResultError(f"{refused}{told}")


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


@lru_cache(maxsize=1)
def _versions() -> dict[str, str]:
    """The distributions' versions (read once per process: installing a package changes a process's
    modules no more)."""
    out = {}
    for name in _PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def stages_until(until: str | None, stages: tuple[Stage, ...] = STAGES) -> tuple[Stage, ...]:
    """The stages to run, ending with the one named ``until`` (all when None)."""
    names = available_stages(stages)
    if until is None:
        return stages
    if until not in names:
        raise StageError(f"--until {until!r}: unknown stage; expected one of {', '.join(names)}")
    return stages[: names.index(until) + 1]


def _run_stage(ctx: RunContext, stage: Stage, keep_products: bool, out: Path, writer: Executor) -> dict:
    """Run one stage, or reuse its cached result (:mod:`fracture.pipeline.cache`); returns what the manifest says of it.

    The stage's result is what it adds to the context: files, products (kept
    only for stages whose products a later stage reads), counts, statistics
    and notes. It is stored into the cache by ``writer`` while the next
    stages run (the manifest's ``cache`` is a future until the run ends,
    :func:`_stored`): a preview's fields entry, tens of megabytes, is written
    while the surface is refined. Later stages neither change an earlier
    stage's files nor its products (the animate stage copies the refined
    surface), so the entry is what the stage made.
    """
    name, cache = stage.name, ctx.cache
    if cache is None:
        stage.run(ctx)
        return {}
    from fracture.pipeline.cache import stage_key

    previous = next(reversed(ctx.keys.values()), "")
    key = ctx.keys[name] = stage_key(name, ctx.config, previous)
    entry = cache.load(name, key)
    products = cache.restore(entry, ctx.dir) if entry is not None else None
    if products is not None:
        ctx.files.extend(rel for rel in entry.files if rel not in ctx.files)
        ctx.products.update(products)
        ctx.counts.update(entry.meta["counts"])
        ctx.stats.update(entry.meta["stats"])
        ctx.notes.extend(entry.meta["notes"])
        ctx.say(f"{name}: reused from the cache ({entry.path}; made by {entry.meta['run']})")
        log.info("%s: reused from the cache entry %s", name, entry.path)
        return {"cache": "reused", "cache_entry": str(entry.path), "made_by": entry.meta["run"]}
    n_files, n_notes = len(ctx.files), len(ctx.notes)
    products, counts, stats = ctx.products.made(), dict(ctx.counts), dict(ctx.stats)
    stage.run(ctx)
    changed = lambda new, old: {k: v for k, v in new.items() if k not in old or old[k] is not v}  # noqa: E731
    meta = dict(counts=changed(ctx.counts, counts), stats=changed(ctx.stats, stats), notes=ctx.notes[n_notes:],
                run=str(out))
    args = (name, key, ctx.dir, ctx.files[n_files:], changed(ctx.products.made(), products) if keep_products else {},
            meta)
    return {"cache": writer.submit(cache.store, *args)}


def _threads() -> dict:
    """The parallel kernels' threads and threading layer (``none``: no parallel kernel ran in this process),
    and on GNU OpenMP how its threads wait between kernels (:data:`fracture.process.WAIT_POLICY`)."""
    import numba

    try:
        layer = numba.threading_layer()
    except ValueError:  # numba starts its threading layer with the first parallel kernel
        layer = "none"
    threads = {"threads": numba.get_num_threads(), "layer": layer}
    if layer == "omp":
        threads["wait"] = os.environ.get("OMP_WAIT_POLICY", "default").lower()
    return threads


def _stored(entry: Path | None) -> str:
    return "stored" if entry is not None else "not stored (the cache cannot be written)"


def run(cfg: Config, out: str | Path, until: str | None = None, force: bool = False, progress: bool = True,
        listener=None, cache=None, stages: tuple[Stage, ...] = STAGES) -> Path:
    """Run the configured stages into the run directory ``out``.

    Parameters
    ----------
    cfg : Config
        A resolved config from :func:`fracture.pipeline.config.load_config`.
    out : str or Path
        Run directory; must not exist (or be empty) unless ``force``.
    until : str, optional
        Last stage to run.
    force : bool
        Replace an existing run directory (only once the new run succeeded).
    progress : bool
        Show progress bars on stderr.
    listener : callable, optional
        ``listener(event, data)``: ``("stage", {"name"})`` before each stage and
        ``("iteration", {...})`` after each refinement iteration (positions,
        faces, psi, speed, energy, iteration), from the running thread.
    cache : StageCache, optional
        Reuse and store stage results (:mod:`fracture.pipeline.cache`).
    stages : tuple of Stage
        The pipeline (default :data:`~fracture.pipeline.stages.STAGES`); a stage of one's own replaces
        one of the same name.

    Returns
    -------
    Path
        The run directory, holding ``config.yaml``, ``manifest.json`` and the
        stages' outputs.
    """
    chosen = stages_until(until, stages)
    started = datetime.now(timezone.utc)
    manifest: dict[str, Any] = {
        "name": cfg.name,
        "seed": cfg.seed,
        "started": started.isoformat(timespec="seconds"),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "packages": dict(_versions()),
        "stages": {},
    }
    # the stages' files and the cache's entries are written by one thread beside the stages, in the
    # order given (an entry copies its stage's files), all before the run is complete and before a
    # failed run's directory is removed
    with staged_directory(out, force) as staging, ThreadPoolExecutor(1, "fracref-writer") as writer:
        ctx = RunContext(config=cfg, dir=staging, progress=progress, listener=listener, cache=cache, writer=writer)
        ctx.path(layout.CONFIG).write_text(dump_config(cfg), encoding="utf-8")
        before: dict[str, _Before] = {}  # what the context held when each stage began
        first_draw, refusals = cfg.refine.draw, []  # refinements refused so far: their notes
        spent: dict[str, float] = {}  # seconds per stage, every try
        at = 0
        while at < len(chosen):
            stage = chosen[at]
            t0 = time.perf_counter()
            before[stage.name] = _Before.of(ctx)
            ctx.tell("stage", name=stage.name)
            log.info("%s: started", stage.name)
            try:
                info = _run_stage(ctx, stage, keep_products=stage is not stages[-1], out=Path(out), writer=writer)
            except (JoinError, ResultError) as refused:
                again = _again(ctx, first_draw) if "refine" in before else None
                if again is None:
                    raise _after_tries(refused, len(refusals) + 1, ctx.config.refine.draw) from None
                spent[stage.name] = spent.get(stage.name, 0.0) + time.perf_counter() - t0
                _undo_refinement(ctx, again, refused, manifest, before["refine"], refusals)
                at = next(i for i, s in enumerate(chosen) if s.name == "refine")
                continue
            spent[stage.name] = spent.get(stage.name, 0.0) + time.perf_counter() - t0
            manifest["stages"][stage.name] = {"seconds": round(spent[stage.name], 4), **info}
            if stage.name == "refine" and refusals:
                manifest["stages"]["refine"].update(tries=len(refusals) + 1, draw=ctx.config.refine.draw,
                                                    without_search=ctx.config.refine.search != cfg.refine.search)
            log.info("%s: done in %.2f s", stage.name, manifest["stages"][stage.name]["seconds"])
            at += 1
        ctx.wait_for_files()  # before their hashes (a write that failed fails the run)
        for info in manifest["stages"].values():
            if isinstance(info.get("cache"), Future):
                info["cache"] = _stored(info["cache"].result())
        if cache is not None:
            cache.trim()  # once per run: it walks every entry
        manifest["stats"] = ctx.stats
        manifest["counts"] = ctx.counts
        manifest["threads"] = _threads()
        manifest["notes"] = ctx.notes
        manifest["finished"] = datetime.now(timezone.utc).isoformat(timespec="seconds")
        manifest["files"] = {rel: {"sha256": _sha256(staging / rel), "bytes": (staging / rel).stat().st_size}
                             for rel in sorted(ctx.files)}
        # Written last: a directory with a manifest is a complete run.
        (staging / layout.MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n", encoding="utf-8")
    return Path(out)

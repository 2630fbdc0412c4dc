"""The experiment runner: configured stages in order, one run directory.

Stages register themselves with :func:`stage` under one of the names in
:data:`STAGE_ORDER`; :func:`run` executes the registered ones in that order
(up to ``until``) inside a staging directory, then writes ``config.yaml`` and
``manifest.json`` and moves the directory into place (see
:mod:`fracture.atomic`). Stages hand in-memory results to later stages through
``RunContext.products`` and write their files with the ``RunContext.save_*``
helpers, which record each file for the manifest.
"""

from __future__ import annotations

import hashlib
import json
import platform
import sys
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path
from typing import Any, Callable

import numpy as np
from tqdm.auto import tqdm

from fracture.atomic import png_bytes, staged_directory
from fracture.config import dump_config
from fracture.errors import StageError

STAGE_ORDER = ("coarse", "fields", "refine", "animate", "render")

_REGISTRY: dict[str, Callable[["RunContext"], None]] = {}

# Distributions whose versions go into the manifest.
_PACKAGES = ("numpy", "scipy", "numba", "open3d", "pymeshlab", "libigl", "noise", "PyYAML", "imageio", "fracref")


def stage(name: str):
    """Register ``func(ctx)`` as the stage ``name``."""
    if name not in STAGE_ORDER:
        raise ValueError(f"unknown stage {name!r}, expected one of {', '.join(STAGE_ORDER)}")

    def register(func):
        _REGISTRY[name] = func
        return func

    return register


def available_stages() -> list[str]:
    """Registered stages, in pipeline order."""
    _load_stage_modules()
    return [s for s in STAGE_ORDER if s in _REGISTRY]


def _load_stage_modules() -> None:
    import fracture.stages  # noqa: F401  (registers the stages)


@dataclass
class RunContext:
    """What a stage sees: the config, its output directory and earlier products."""

    cfg: dict
    dir: Path
    progress: bool = True
    products: dict[str, Any] = field(default_factory=dict)
    counts: dict[str, Any] = field(default_factory=dict)
    stats: dict[str, Any] = field(default_factory=dict)
    files: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    # called as listener(event, data) by stages that report as they go (the viewer's re-run)
    listener: Any = None
    # the stage cache (fracture.cache.StageCache) or None, and the keys of the stages run so far
    cache: Any = None
    keys: dict[str, str] = field(default_factory=dict)

    def tell(self, event: str, **data) -> None:
        if self.listener is not None:
            self.listener(event, data)

    def path(self, rel: str) -> Path:
        """Absolute path of an output file, recorded for the manifest."""
        p = self.dir / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        if rel not in self.files:
            self.files.append(rel)
        return p

    def save_array(self, rel: str, array: np.ndarray) -> None:
        """A ``.npy`` file (byte-identical for identical arrays)."""
        with open(self.path(rel), "wb") as f:
            np.save(f, np.ascontiguousarray(array), allow_pickle=False)

    def save_npz(self, rel: str, arrays: dict[str, np.ndarray]) -> None:
        """An uncompressed ``.npz`` with fixed member timestamps (byte-identical for identical arrays)."""
        import io
        import zipfile

        with zipfile.ZipFile(self.path(rel), "w", zipfile.ZIP_STORED) as z:
            for name, a in arrays.items():
                buf = io.BytesIO()
                np.save(buf, np.ascontiguousarray(a), allow_pickle=False)
                z.writestr(zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0)), buf.getvalue())

    def save_json(self, rel: str, data: Any) -> None:
        self.path(rel).write_text(json.dumps(data, indent=2, sort_keys=True) + "\n", encoding="utf-8")

    def save_png(self, rel: str, image: np.ndarray) -> None:
        self.path(rel).write_bytes(png_bytes(image))

    def bar(self, total: int, desc: str):
        """A progress bar (silent when progress is off); it stays on screen when done."""
        return tqdm(total=total, desc=desc, disable=not self.progress, leave=True, file=sys.stderr)

    def say(self, text: str) -> None:
        """A line for the user among the progress bars (silent when progress is off)."""
        if self.progress:
            tqdm.write(text, file=sys.stderr)


def timing_table(manifest: dict) -> str:
    """Seconds per stage and in all, as a small table (printed at the end of a run)."""
    stages = manifest.get("stages", {})
    width = max([len(n) for n in stages] + [5])
    rows = [f"  {name:<{width}}  {info['seconds']:8.1f} s" for name, info in stages.items()]
    total = sum(info["seconds"] for info in stages.values())
    return "\n".join(["time per stage:", *rows, f"  {'total':<{width}}  {total:8.1f} s"])


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _versions() -> dict[str, str]:
    out = {}
    for name in _PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def stages_until(until: str | None) -> list[str]:
    """The registered stages to run, ending with ``until`` (all when None)."""
    stages = available_stages()
    if until is None:
        return stages
    if until not in STAGE_ORDER:
        raise StageError(f"--until {until!r}: unknown stage; expected one of {', '.join(stages)}")
    if until not in stages:
        raise StageError(f"--until {until!r}: that stage is not available yet; available: {', '.join(stages)}")
    return stages[: stages.index(until) + 1]


def _run_stage(ctx: RunContext, name: str, keep_products: bool, out: Path) -> dict:
    """Run one stage, or reuse its cached result (:mod:`fracture.cache`); returns what the manifest says of it.

    The stage's result is what it adds to the context: files, products (kept
    only for stages whose products a later stage reads), counts, statistics
    and notes.
    """
    cache = ctx.cache
    if cache is None:
        _REGISTRY[name](ctx)
        return {}
    from fracture.cache import stage_key

    previous = next(reversed(ctx.keys.values()), "")
    key = ctx.keys[name] = stage_key(name, ctx.cfg, previous)
    entry = cache.load(name, key)
    products = cache.restore(entry, ctx.dir) if entry is not None else None
    if products is not None:
        ctx.files.extend(rel for rel in entry.files if rel not in ctx.files)
        ctx.products.update(products)
        ctx.counts.update(entry.meta["counts"])
        ctx.stats.update(entry.meta["stats"])
        ctx.notes.extend(entry.meta["notes"])
        ctx.say(f"{name}: reused from the cache ({entry.path}; made by {entry.meta['run']})")
        return {"cache": "reused", "cache_entry": str(entry.path), "made_by": entry.meta["run"]}
    n_files, n_notes = len(ctx.files), len(ctx.notes)
    products, counts, stats = dict(ctx.products), dict(ctx.counts), dict(ctx.stats)
    _REGISTRY[name](ctx)
    changed = lambda new, old: {k: v for k, v in new.items() if k not in old or old[k] is not v}  # noqa: E731
    meta = dict(counts=changed(ctx.counts, counts), stats=changed(ctx.stats, stats), notes=ctx.notes[n_notes:],
                run=str(out))
    stored = cache.store(name, key, ctx.dir, ctx.files[n_files:],
                         changed(ctx.products, products) if keep_products else {}, meta)
    return {"cache": "stored" if stored is not None else "not stored (the cache cannot be written)"}


def run(cfg: dict, out: str | Path, until: str | None = None, force: bool = False, progress: bool = True,
        listener=None, cache=None) -> Path:
    """Run the configured stages into the run directory ``out``.

    Parameters
    ----------
    cfg : dict
        A resolved config from :func:`fracture.config.load_config`.
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

    Returns
    -------
    Path
        The run directory, holding ``config.yaml``, ``manifest.json`` and the
        stages' outputs.
    """
    names = stages_until(until)
    started = datetime.now(timezone.utc)
    manifest: dict[str, Any] = {
        "name": cfg["name"],
        "seed": cfg["seed"],
        "started": started.isoformat(timespec="seconds"),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "packages": _versions(),
        "stages": {},
    }
    with staged_directory(out, force) as staging:
        ctx = RunContext(cfg=cfg, dir=staging, progress=progress, listener=listener, cache=cache)
        ctx.path("config.yaml").write_text(dump_config(cfg), encoding="utf-8")
        for name in names:
            t0 = time.perf_counter()
            ctx.tell("stage", name=name)
            info = _run_stage(ctx, name, keep_products=name != available_stages()[-1], out=Path(out))
            manifest["stages"][name] = {"seconds": round(time.perf_counter() - t0, 4), **info}
        if cache is not None:
            cache.trim()  # once per run: it walks every entry
        manifest["stats"] = ctx.stats
        manifest["counts"] = ctx.counts
        manifest["notes"] = ctx.notes
        manifest["finished"] = datetime.now(timezone.utc).isoformat(timespec="seconds")
        manifest["files"] = {rel: {"sha256": _sha256(staging / rel), "bytes": (staging / rel).stat().st_size}
                             for rel in sorted(ctx.files)}
        # Written last: a directory with a manifest is a complete run.
        (staging / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n", encoding="utf-8")
    return Path(out)

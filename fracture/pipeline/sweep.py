"""Sweeps: one experiment config run over the product of value lists, into one sweep directory.

``fracref sweep CONFIG --grid psi.stress_weight=0.2,0.6,2 --grid seed=0,1,2`` (or a ``sweep.grid``
block in the config) runs every combination of the values as its own run, with the stage cache,
into ``OUT/<key>=<value>,<key>=<value>/``. The sweep directory also holds

* ``sweep.json``: the config, the grid and every point's status (``ok``, ``failed`` with its
  error, ``done before``), rewritten as points finish;
* ``table.csv`` and ``table.md``: each point's figures (:func:`point_figures`: seconds,
  triangles, iterations, energy and the fidelity figures of :mod:`fracture.fidelity`).

A sweep is resumable: a point whose run directory is complete (it has its manifest) and was run with
the config and stages asked for now is not run again (one whose config or ``--until`` changed is run
again, and its earlier run replaced once the new one is complete), and each run is moved into place whole (:mod:`fracture.io.atomic`), so a killed sweep loses
only the points that were running. A failed point is listed with its error and does not stop
the others. Every point's config is checked before anything runs.

Points run in this process (``jobs=1``), in local processes (``jobs > 1``), or on Ray
(``backend="ray"``): ``ray.init(address)`` joins an existing cluster (``None``: a local one with
``jobs`` CPUs). A Ray task runs its point into a temporary directory on its node and returns the
run directory's files, which are written into the sweep directory where the sweep was started;
the inputs a config names must be readable at the same paths on every node.
"""

from __future__ import annotations

import csv
import functools
import io
import itertools
import json
import re
import signal
import tarfile
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator

import yaml

from fracture.io import layout
from fracture.io.atomic import atomic_write_text, staged_directory
from fracture.pipeline.config import dump_config, load_config, load_yaml
from fracture.errors import ConfigError

GRID_SOURCE = "--grid"
BACKENDS = ("local", "ray")


@dataclass(frozen=True)
class Point:
    """One combination of values: ``((key, value), ...)`` in the grid's order."""

    values: tuple[tuple[str, Any], ...]

    @property
    def name(self) -> str:
        """The run directory's name, e.g. ``psi.stress_weight=0.2,seed=1``."""
        text = ",".join(f"{k}={json.dumps(v, separators=(',', ':'))}" for k, v in self.values)
        return re.sub(r"[^\w.=,\-\[\]:]", "_", text)

    @property
    def overrides(self) -> list[str]:
        """``key=value`` overrides for :func:`fracture.pipeline.config.load_config` (values as YAML)."""
        return [f"{k}={json.dumps(v)}" for k, v in self.values]

    @property
    def label(self) -> str:
        return ", ".join(f"{k} = {v}" for k, v in self.values)


def parse_grid(texts: Iterable[str]) -> dict[str, list]:
    """``["key=v1,v2", ...]`` as ``{key: [v1, v2]}`` (each value read as YAML)."""
    grid: dict[str, list] = {}
    for text in texts:
        key, sep, raw = text.partition("=")
        key = key.strip()
        if not sep or not key or not raw.strip():
            raise ConfigError(GRID_SOURCE, key, f"got {text!r}, expected key.path=value1,value2,...")
        if key in grid:
            raise ConfigError(GRID_SOURCE, key, "given twice; expected each key once")
        try:
            values = [load_yaml(v) for v in _split_values(raw)]
        except yaml.YAMLError:
            raise ConfigError(GRID_SOURCE, key, f"cannot read the values {raw!r} as YAML") from None
        grid[key] = values
    return grid


def _split_values(raw: str) -> list[str]:
    """Split at commas outside brackets (``grid.resolution=[20,20,20],30``)."""
    parts, depth, start = [], 0, 0
    for i, c in enumerate(raw):
        depth += c in "[{"
        depth -= c in "]}"
        if c == "," and depth == 0:
            parts.append(raw[start:i])
            start = i + 1
    parts.append(raw[start:])
    return [p.strip() for p in parts]


def points(grid: dict[str, list]) -> list[Point]:
    """Every combination of the grid's values (the last key varying fastest); a value given twice for a key
    (``0.2,0.2``, or ``1,01``: both 1) is refused, as its two points would be one run."""
    keys = list(grid)
    for k in keys:
        seen: dict[str, str] = {}
        for v in grid[k]:
            text, same = json.dumps(v, sort_keys=True), json.dumps(_as_numbers(v), sort_keys=True)
            if same in seen:
                twice = text if seen[same] == text else f"{seen[same]} (and {text}, the same number)"
                raise ConfigError(GRID_SOURCE, k, f"the value {twice} is given twice; expected distinct values")
            seen[same] = text
    out = [Point(tuple(zip(keys, combo))) for combo in itertools.product(*(grid[k] for k in keys))]
    named: dict[str, Point] = {}
    for point in out:  # two values whose folder names are one (characters a path cannot hold become _)
        if point.name in named:
            raise ConfigError(GRID_SOURCE, ",".join(keys), f"the points {named[point.name].label} and {point.label} "
                              f"would share the folder {point.name!r}; expected values that differ in letters, "
                              "digits or . = , - [ ] :")
        named[point.name] = point
    return out


def _as_numbers(v):
    """``v`` with every number a float (1 and 1.0 are one value of a key), in lists and mappings too."""
    if isinstance(v, bool):
        return v
    if isinstance(v, (int, float)):
        return float(v)
    if isinstance(v, list):
        return [_as_numbers(x) for x in v]
    if isinstance(v, dict):
        return {k: _as_numbers(x) for k, x in v.items()}
    return v


def check_points(config: Path, base: list[str], pts: list[Point]) -> dict[str, str]:
    """Load every point's config, so that a bad value stops the sweep before anything runs (naming the point);
    returns each point's config as its run writes it (``config.yaml``), by the point's name."""
    out = {}
    for p in pts:
        try:
            out[p.name] = dump_config(load_config(config, base + p.overrides))
        except ConfigError as exc:
            raise ConfigError(f"{config} at the sweep point {p.label}", exc.key, exc.problem) from None
    return out


def _stale(run_dir: Path, config_text: str, until: str | None) -> str | None:
    """Why the complete run ``run_dir`` of a point is not the run asked for now (None: it is): another config
    (the sweep's config file, ``--set`` or the grid changed since) or other stages (``--until``)."""
    from fracture.pipeline.runner import stages_until

    try:
        written = (run_dir / layout.CONFIG).read_text(encoding="utf-8")
        ran = list(layout.read_manifest(run_dir)["stages"])
    except (OSError, ValueError, KeyError, TypeError):
        return "its run directory cannot be read"
    if written != config_text:
        return "its config changed"
    if ran != [s.name for s in stages_until(until)]:
        return "it ran other stages (--until)"
    return None


# -- running one point ---------------------------------------------------------------------------

def run_point(config: str, overrides: list[str], out: str, until: str | None, cache_dir: str | None,
              use_cache: bool, force: bool = False) -> dict:
    """Run one point into ``out`` (a worker's task; ``force`` replaces an earlier run there once this one is
    complete); returns its status, never raises for a failed run."""
    from fracture.pipeline import runner
    from fracture.pipeline.cache import StageCache

    start = time.perf_counter()
    try:
        cfg = load_config(config, overrides)
        runner.run(cfg, out, until=until, force=force, progress=False,
                   cache=StageCache(cache_dir) if use_cache else None)
        return {"status": "ok", "seconds": round(time.perf_counter() - start, 3)}
    except Exception as exc:  # noqa: BLE001 - a failed point is reported, the others go on
        return {"status": "failed", "error": _said(exc), "seconds": round(time.perf_counter() - start, 3)}


def _said(exc: BaseException) -> str:
    """A failed point's error in the user's words: the project's own errors as they are, anything else with
    its kind (it is not one the project foresaw)."""
    from fracture.errors import ResultError, StageError
    from fracture.io.atomic import OutputError, RunDirectoryExists
    from fields.errors import InputError

    if isinstance(exc, (ConfigError, InputError, StageError, ResultError, OutputError, RunDirectoryExists)):
        return str(exc)
    return f"{type(exc).__name__}: {exc}"


def run_point_archived(config: str, overrides: list[str], until: str | None, cache_dir: str | None,
                       use_cache: bool) -> tuple[dict, bytes]:
    """Run one point into a temporary directory (a Ray task, on any node) and return its status and the
    run directory as an uncompressed tar archive (empty when it failed)."""
    with tempfile.TemporaryDirectory(prefix="fracref-point-") as tmp:
        out = Path(tmp) / "run"
        status = run_point(config, overrides, str(out), until, cache_dir, use_cache)
        if status["status"] != "ok":
            return status, b""
        buf = io.BytesIO()
        with tarfile.open(fileobj=buf, mode="w") as tar:
            tar.add(out, arcname=".")
        return status, buf.getvalue()


def unpack_run(archive: bytes, out: Path, force: bool = False) -> None:
    """Write a run directory from :func:`run_point_archived`'s archive into place whole (``force``: replacing
    an earlier run there)."""
    with staged_directory(out, force) as staging:
        with tarfile.open(fileobj=io.BytesIO(archive), mode="r") as tar:
            tar.extractall(staging, filter="data")


# -- backends ------------------------------------------------------------------------------------

def _local(tasks: list[tuple[Point, tuple]], jobs: int) -> Iterator[tuple[Point, dict]]:
    if jobs <= 1:
        for p, args in tasks:
            yield p, run_point(*args)
        return
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from fracture.process import cores

    # fresh interpreters (spawn: nothing of this process's threads), each set up as the command line is,
    # its kernels on its share of the cores
    setup = functools.partial(_worker_setup, threads=max(1, cores() // jobs))
    pool = ProcessPoolExecutor(max_workers=jobs, mp_context=mp.get_context("spawn"), initializer=setup)
    try:
        futures = {pool.submit(run_point, *args): p for p, args in tasks}
        for f in as_completed(futures):
            yield futures[f], f.result()
    except BaseException:  # Ctrl-C, a signal, the caller gone: the points still running are stopped, not awaited
        workers = list((getattr(pool, "_processes", None) or {}).values())
        stop_workers(workers, signalled=lambda: pool.shutdown(wait=False, cancel_futures=True))
        raise
    pool.shutdown()


def stop_workers(workers: list, grace: float | None = None, signalled=None) -> None:
    """Stop worker processes: SIGTERM, which each unwinds as from Ctrl-C (:func:`_worker_setup`; then
    ``signalled()``, if given), and, for one still alive after ``grace`` seconds (default ``_WORKER_GRACE``),
    SIGKILL: the pool's threads, which the interpreter joins on its way out, wait for every worker, and a
    sweep stopped under load was seen to hang there for minutes after it had said it stopped. A killed worker
    may leave its point's staging behind; the next write there clears it (:mod:`fracture.io.atomic`)."""
    grace = _WORKER_GRACE if grace is None else grace
    for proc in workers:
        proc.terminate()
    if signalled is not None:
        signalled()
    deadline = time.monotonic() + grace
    for proc in workers:
        proc.join(max(0.0, deadline - time.monotonic()))
    for proc in workers:
        if proc.is_alive():
            proc.kill()
            proc.join()


def _worker_setup(threads: int) -> None:
    """A sweep worker: set up as the command line is; Ctrl-C is the sweep's to answer (it stops its workers),
    not each worker's (each printed a traceback of wherever it was). The sweep stops a worker with SIGTERM: it
    unwinds as from Ctrl-C, so the run it was writing removes its staging (killed at once, it stayed in the
    sweep's folder)."""
    from fracture.process import prepare_process

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _stopped_worker)
    prepare_process(threads=threads)


def _stopped_worker(signum, frame):
    from fracture.process import later_if_compiling

    if not later_if_compiling(signum, frame):  # a kernel being compiled: once it is written
        raise KeyboardInterrupt


# Seconds the sweep waits for its stopped workers to remove what they were writing.
_WORKER_GRACE = 10.0


def _ray_start(jobs: int, address: str | None) -> bool:
    """Join the Ray cluster at ``address`` (None: start a local one with ``jobs`` CPUs), or refuse in one
    line; returns whether this call started Ray (and so must shut it down)."""
    try:
        import ray
    except ImportError:
        raise ConfigError("--backend", "ray", "Ray is not installed; expected `pip install fracref[ray]` "
                          "(or `pip install ray`)") from None
    if ray.is_initialized():
        return False
    _check_reachable(address)
    try:
        ray.init(address=address, num_cpus=None if address else max(jobs, 1), include_dashboard=False,
                 log_to_driver=False, configure_logging=False)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise ConfigError("--address", str(address), f"cannot join a Ray cluster there ({exc}); expected the "
                          "head's address (ray start --head prints it), ray://HOST:10001 or auto") from None
    return True


def _ray(tasks: list[tuple[Point, tuple]], started: bool, root: Path) -> Iterator[tuple[Point, dict]]:
    """Run the points as Ray tasks (Ray joined by :func:`_ray_start`), writing each finished run into ``root``."""
    import ray

    try:
        remote = ray.remote(num_cpus=1, max_retries=0)(run_point_archived)
        refs = {}
        replace = {}
        for p, (config, overrides, out, until, cache_dir, use_cache, force) in tasks:
            refs[remote.remote(config, overrides, until, cache_dir, use_cache)] = p
            replace[p.name] = force
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1)
            p = refs.pop(done[0])
            try:
                status, archive = ray.get(done[0])
            except Exception as exc:  # noqa: BLE001 - a lost worker fails its point only
                status, archive = {"status": "failed", "error": _said(exc)}, b""
            if status["status"] == "ok":
                unpack_run(archive, root / p.name, replace[p.name])
            yield p, status
    finally:
        if started:
            ray.shutdown()


def _check_reachable(address: str | None, seconds: float = 5.0) -> None:
    """Refuse at once an address ``HOST:PORT`` (or ``ray://HOST:PORT``) where nothing answers (Ray itself
    keeps retrying for minutes)."""
    import socket

    if not address or address == "auto":
        return
    host, _, port = address.split("://")[-1].rpartition(":")
    if not host or not port.isdigit():
        raise ConfigError("--address", address, "expected HOST:PORT, ray://HOST:PORT or auto")
    try:
        socket.create_connection((host, int(port)), timeout=seconds).close()
    except OSError as exc:
        raise ConfigError("--address", address, f"no Ray cluster answers there ({exc.strerror or exc}); expected "
                          "the address of a running head (ray start --head prints it), or auto") from None


# -- the sweep -------------------------------------------------------------------------------------

def run_sweep(config: str | Path, grid: dict[str, list], out: str | Path, overrides: Iterable[str] = (),
              jobs: int = 1, backend: str = "local", address: str | None = None, until: str | None = None,
              cache_dir: str | Path | None = None, use_cache: bool = True, progress: bool = True) -> dict:
    """Run the sweep (module notes) and write ``sweep.json`` and the tables; returns ``sweep.json``'s content."""
    from tqdm.auto import tqdm

    config, out, base = Path(config).resolve(), Path(out).resolve(), list(overrides)
    if backend not in BACKENDS:
        raise ConfigError("--backend", backend, f"expected one of {', '.join(BACKENDS)}")
    if not grid:
        raise ConfigError(GRID_SOURCE, "", "no values to sweep; expected --grid key=v1,v2 or a sweep.grid block")
    pts = points(grid)
    configs = check_points(config, base, pts)
    if out.exists() and not out.is_dir():
        raise ConfigError("--out", str(out), "is a file; expected a sweep directory")
    started = _ray_start(jobs, address) if backend == "ray" else False
    out.mkdir(parents=True, exist_ok=True)
    state = {"config": str(config), "overrides": base, "grid": grid, "backend": backend, "points": {}}
    todo = []
    for p in pts:
        complete = (out / p.name / layout.MANIFEST).is_file()
        stale = _stale(out / p.name, configs[p.name], until) if complete else None
        if complete and stale is None:
            state["points"][p.name] = {"values": dict(p.values), "status": "done before"}
        else:
            state["points"][p.name] = {"values": dict(p.values), "status": "pending"}
            if stale is not None:  # run again; the earlier run is replaced once the new one is complete
                state["points"][p.name]["replaces"] = f"an earlier run: {stale}"
            todo.append((p, (str(config), base + p.overrides, str(out / p.name), until,
                             None if cache_dir is None else str(cache_dir), use_cache, complete)))
    save = lambda: atomic_write_text(out / "sweep.json", json.dumps(state, indent=1, default=str) + "\n")  # noqa: E731
    save()
    bar = tqdm(total=len(todo), desc="sweep", disable=not progress, leave=True)
    runs = _ray(todo, started, out) if backend == "ray" else _local(todo, jobs)
    for p, status in runs:
        state["points"][p.name].update(status)
        save()
        bar.set_postfix_str(f"{p.name}: {status['status']}")
        bar.update()
    bar.close()
    rows = [dict(point=name, **{k: v for k, v in info["values"].items()}, status=info["status"],
                 **(point_figures(out / name) if info["status"] in ("ok", "done before") else {}),
                 error=info.get("error", "")) for name, info in state["points"].items()]
    write_tables(out, rows)
    return state


def point_figures(run_dir: Path) -> dict:
    """A finished point's figures: seconds, refined triangles, iterations, the last plain energy and
    functional, and (with a refine stage) the fidelity figures of :func:`fracture.fidelity.run_figures`."""
    manifest = layout.read_manifest(run_dir)
    out: dict[str, Any] = {"seconds": round(sum(s["seconds"] for s in manifest["stages"].values()), 3),
                           "reused_stages": sum(s.get("cache") == "reused" for s in manifest["stages"].values())}
    refine = manifest.get("stats", {}).get("refine")
    if refine is None:
        return out
    from fracture.fidelity import run_figures

    f = run_figures(run_dir)
    out.update(triangles=f["triangles"], iterations=f["iterations"], energy=refine["energy"][-1],
               functional=refine["functional"][-1], refine_seconds=f["seconds"])
    for q in (10, 20, 30):
        out[f"weak_{q}_coarse"] = f["coarse"][f"weak_share_{q}"]
        out[f"weak_{q}"] = f["refined"][f"weak_share_{q}"]
    out.update(mean_zeta_coarse=f["coarse"]["mean_zeta"], mean_zeta=f["refined"]["mean_zeta"],
               distance_mean=f["refined"]["distance_mean"], distance_p90=f["refined"]["distance_p90"])
    return out


def write_tables(out: Path, rows: list[dict]) -> None:
    """``table.csv`` and ``table.md`` of the points' rows (columns: the union of their keys, in order)."""
    columns: list[str] = []
    for r in rows:
        columns += [k for k in r if k not in columns]
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_text(out / "table.csv", buf.getvalue())

    def cell(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v).replace("|", "\\|").replace("\n", " ")

    lines = ["| " + " | ".join(columns) + " |", "| " + " | ".join("---" for _ in columns) + " |"]
    lines += ["| " + " | ".join(cell(r.get(c, "")) for c in columns) + " |" for r in rows]
    atomic_write_text(out / "table.md", "\n".join(lines) + "\n")


def finished(state: dict) -> list[str]:
    """The names of the points that have a complete run."""
    return [name for name, info in state["points"].items() if info["status"] in ("ok", "done before")]


__all__ = ["Point", "parse_grid", "points", "run_sweep", "point_figures", "write_tables", "finished",
           "run_point", "run_point_archived", "unpack_run"]

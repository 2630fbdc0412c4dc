"""``fracref``: the command line.

``fracref run CONFIG [--out DIR] [--set key.path=value ...] [--until STAGE] [--force] [--no-cache]``
``fracref config CONFIG [--set ...]`` prints the resolved config; ``fracref config --explain KEY`` what a key means.
``fracref --log-level info ...`` shows the library's messages on stderr.
``fracref stages`` lists the stages.
``fracref export RUN_DIR --format usd [--out FILE]`` writes a finished run's animated pieces as USD.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

from fracture.process import environment_problem, on_main_thread  # they load nothing (numba neither)


# commands that refine or load refinement results (the others only read configs)
_COMPUTING = ("run", "sweep", "view", "render", "export", "compile")
_DRAWING = ("view", "render", "sweep")  # the commands that may draw (a sweep its contact sheet)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fracref", description="Physics-inspired adaptive fracture refinement.")
    p.add_argument("--log-level", default="warning", choices=["warning", "info", "debug"],
                   help="messages of the library to show on stderr (default: warning)")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    r = sub.add_parser("run", help="run an experiment config into a run directory")
    r.add_argument("config", type=Path, help="experiment YAML file")
    r.add_argument("--out", type=Path, help="run directory (default: runs/<name>)")
    r.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
                   help="override a config value (YAML syntax); repeatable")
    r.add_argument("--until", metavar="STAGE", help="last stage to run")
    r.add_argument("--force", action="store_true", help="replace an existing run directory")
    r.add_argument("--quiet", action="store_true", help="no progress bars")
    _cache_flags(r)

    w = sub.add_parser("sweep", help="run a config over every combination of values into one sweep directory")
    w.add_argument("config", type=Path, help="experiment YAML file (its sweep.grid block, if any, is swept)")
    w.add_argument("--grid", action="append", default=[], metavar="KEY.PATH=V1,V2,...",
                   help="values of a config key to sweep (YAML values, comma-separated); repeatable; replaces the "
                        "config's sweep.grid")
    w.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
                   help="override a config value at every point; repeatable")
    w.add_argument("--out", type=Path, help="sweep directory (default: runs/<name>-sweep)")
    w.add_argument("--jobs", type=int, default=1, metavar="N", help="points run at once (default 1)")
    w.add_argument("--backend", default="local", choices=["local", "ray"],
                   help="local processes, or Ray (pip install 'fracref[ray]')")
    w.add_argument("--address", help="ray: the cluster to join (e.g. auto, or ray://HOST:10001); default: a "
                   "local Ray with --jobs CPUs")
    w.add_argument("--until", metavar="STAGE", help="last stage of every point's run")
    w.add_argument("--no-sheet", action="store_true", help="no contact sheet of the refined surfaces")
    w.add_argument("--quiet", action="store_true", help="no progress bar")
    _cache_flags(w)

    k = sub.add_parser("compile", help="compile the kernels now (once per install; make install does it), so that "
                       "the first run does not wait for it")
    k.add_argument("--processes", type=int, choices=(1, 2), default=None, metavar="{1,2}",
                   help="compile in one process, or in two side by side (default: two on a machine of two cores or "
                   "more)")

    c = sub.add_parser("config", help="print the resolved config, or what config keys mean")
    c.add_argument("config", type=Path, nargs="?", help="experiment YAML file (not needed with --explain)")
    c.add_argument("--explain", metavar="KEY", nargs="?", const="",
                   help="say what KEY means (its default, range and description); a section lists its keys; "
                        "no KEY: every key")
    c.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE")

    sub.add_parser("stages", help="list the pipeline stages")
    sub.add_parser("presets", help="list the configs that ship with the package (for defaults: [NAME] in a "
                   "config anywhere)")

    e = sub.add_parser("export", help="write a finished run's animated pieces as one USD file")
    e.add_argument("run_dir", type=Path, metavar="RUN_DIR")
    e.add_argument("--format", default="usd", choices=["usd"], help="output format (default: usd)")
    e.add_argument("--out", type=Path, help="output file (default: RUN_DIR/animation/pieces.usdc)")
    e.add_argument("--force", action="store_true", help="replace --out if it exists")

    v = sub.add_parser("view", help="open the research viewer on a run directory or a config")
    v.add_argument("target", type=Path, metavar="CONFIG_OR_RUN_DIR",
                   help="a run directory, a sweep directory (fracref sweep: choose a point, flip between two), or "
                        "a config (run first into --out, default runs/<name>)")
    v.add_argument("--out", type=Path, help="run directory for a config (default: runs/<name>)")
    v.add_argument("--width", type=int, default=1800)
    v.add_argument("--height", type=int, default=900)
    v.add_argument("--camera", type=Path, metavar="FILE",
                   help="start with the panels and cameras of a view file (Save view) or a saved config")

    d = sub.add_parser("render", help="render figures (PNG) and videos (MP4) of a run with no window")
    d.add_argument("run_dir", type=Path, metavar="RUN_DIR")
    d.add_argument("--what", action="append", choices=["slices", "iterations", "animation", "compare", "turntable"],
                   help="what to render (repeatable; default: those of slices, iterations, animation the run has)")
    d.add_argument("--out", type=Path, help="output directory (default: RUN_DIR/renders)")
    d.add_argument("--width", type=int, default=1280, help="figure width in pixels (compare: both halves)")
    d.add_argument("--height", type=int, default=720)
    d.add_argument("--supersample", type=int, default=1, metavar="K",
                   help="render K times larger and average down (1..4; smoother edges)")
    d.add_argument("--transparent", action="store_true", help="PNGs with a transparent background")
    d.add_argument("--camera", type=Path, metavar="FILE",
                   help="the panels' settings and cameras of a view file (Save view) or a saved config "
                        "(default: the run's config)")
    d.add_argument("--fps", type=int, default=24, help="video frames per second")
    d.add_argument("--image-seconds", type=float, metavar="S",
                   help="how long each image is shown in a video (default: slices 0.4, iterations 0.25, "
                        "animation its own frame rate)")
    d.add_argument("--hold", type=float, default=1.0, metavar="S", help="the last image held S seconds more")
    d.add_argument("--turntable-seconds", type=float, default=6.0, metavar="S", help="length of one turn")
    d.add_argument("--field", help="slices: psi, zeta or xi")
    d.add_argument("--axis", help="slices: normal axis x, y or z")
    d.add_argument("--level", type=int, help="slices: psi's pyramid level (0 = finest)")
    d.add_argument("--cutaway", action=argparse.BooleanOptionalAction, help="slices: the pieces below the slice")
    d.add_argument("--color-by", help="iterations: psi or speed")
    d.add_argument("--frame", type=int, help="compare, turntable: the frame (1 = the first; default: the view "
                   "file's, else the run config's view.frame, and the last when that is 1)")
    d.add_argument("--overlay-coarse", action=argparse.BooleanOptionalAction,
                   help="animation: draw the coarse pieces too")
    d.add_argument("--quiet", action="store_true", help="no progress bars")
    return p


def _cache_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument("--no-cache", action="store_true",
                   help="run every stage (default: reuse the results of stages whose inputs are unchanged)")
    p.add_argument("--cache-dir", type=Path, metavar="DIR",
                   help="the stage cache (default: $FRACREF_CACHE_DIR, else ~/.cache/fracref; at most "
                        "$FRACREF_CACHE_MAX_GB, default 5 GB)")


def cache_from_args(args):
    """The stage cache the flags ask for, or None."""
    from fracture.pipeline.cache import StageCache

    return None if args.no_cache else StageCache(checked_cache_dir(args))


def checked_cache_dir(args) -> Path | None:
    """``--cache-dir``; the cache folder a user named (``--cache-dir`` or ``$FRACREF_CACHE_DIR``) is refused when
    a file stands where it would be or it cannot be written (a cache that cannot be written is otherwise only
    said in the manifest: asked for by name, it is said here), and so is a ``$FRACREF_CACHE_MAX_GB`` that is no
    size."""
    from fracture.errors import InputError
    from fracture.pipeline.cache import default_max_bytes

    d = args.cache_dir
    if args.no_cache:
        return d
    default_max_bytes()
    named = d if d is not None else Path(os.environ.get("FRACREF_CACHE_DIR") or "")
    if not named.name:
        return d
    said = f"--cache-dir {named}" if d is not None else f"FRACREF_CACHE_DIR={named}"
    blocked = next((p for p in (named, *named.parents) if p.exists() and not p.is_dir()), None)
    if blocked is not None:
        raise InputError(f"{said}: {blocked} is a file, not a folder; expected a folder for the stage cache (or "
                         "--no-cache)")
    existing = next((p for p in (named, *named.parents) if p.exists()), None)
    if existing is not None and not os.access(existing, os.W_OK | os.X_OK):
        raise InputError(f"{said}: {existing} cannot be written; expected a folder the stage cache can be written "
                         "to (or --no-cache)")
    return d


class _Stopped(KeyboardInterrupt):
    """Ctrl-C, SIGTERM or SIGHUP while a command runs: unwinds as Ctrl-C does (a run being staged is removed);
    ``code`` is the exit status (130, 143, 129)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.code = 128 + signum


# The signal that stopped the command, once one has (errors it causes while unwinding are said as the stop).
_stopped_by: list[int] = []


def _stop(signum, frame):
    """Ctrl-C, SIGTERM and SIGHUP: raise :class:`_Stopped` where the program is, or a moment later when it is
    inside the compiler's C code (:func:`fracture.process.later_if_compiling`)."""
    from fracture.process import later_if_compiling

    if later_if_compiling(signum, frame):
        return
    _stopped_by.append(signum)
    raise _Stopped(signum)


def main(argv: list[str] | None = None) -> int:
    """The command line; Ctrl-C, SIGTERM and SIGHUP stop it with one line (the previous handlers are restored)."""
    import signal

    problem = environment_problem()  # before anything loads numba, which refuses it with a traceback
    if problem is not None:
        print(f"fracref: error: {problem}", file=sys.stderr)
        return 2
    # SIGHUP: the terminal it ran in was closed
    signals = [signal.SIGINT, signal.SIGTERM, signal.SIGHUP] if on_main_thread() else []
    previous = [signal.signal(s, _stop) for s in signals]
    _stopped_by.clear()
    try:
        return _main(argv)
    except _Stopped as stop:
        return _say_stopped(stop.code, argv, getattr(stop, "run_in_place", None))
    except Exception:
        if _stopped_by:  # a kernel half compiled when the signal came, say: the stop, not what it broke
            return _say_stopped(128 + _stopped_by[0], argv)
        raise
    finally:
        for s, handler in zip(signals, previous):
            signal.signal(s, handler)


def _say_stopped(code: int, argv: list[str] | None, run_in_place: Path | None = None) -> int:
    """One line on what a stop left: a sweep keeps its finished points, a run stopped while the run it replaced
    was deleted is whole, any other command writes nothing."""
    words = list(sys.argv[1:] if argv is None else argv)
    how = {130: "interrupted", 129: "stopped (its terminal closed)"}.get(code, "terminated")
    if run_in_place is not None and words[:1] != ["sweep"]:
        print(f"fracref: {how} after the run was written whole to {run_in_place}; what is left of the run it "
              "replaced goes with the next run there", file=sys.stderr)
    elif words[:1] == ["sweep"]:
        print(f"fracref: {how}; the sweep's finished points are kept (run the same sweep again to resume)",
              file=sys.stderr)
    else:
        print(f"fracref: {how}; nothing was written", file=sys.stderr)
    return code


def _main(argv: list[str] | None) -> int:
    args = _parser().parse_args(argv)
    from fracture.process import prepare_process
    from fracture.io.atomic import OutputError, RunDirectoryExists
    from fracture.pipeline.config import dump_config, load_config
    from fracture.errors import ConfigError, InputError, ResultError, StageError
    from fracture.io import layout

    logging.basicConfig(level=args.log_level.upper(), format="%(name)s: %(message)s", stream=sys.stderr)
    try:
        if args.command in _COMPUTING:
            prepare_process()  # only where kernels run: config, stages and explain need none of it
        if args.command in _DRAWING:
            from viewer.lazy_open3d import defer_open3d_ml

            defer_open3d_ml()  # Open3D without its machine-learning package (1.9 s), which the pictures do not use
        if args.command == "stages":
            from fracture.pipeline import runner

            print("\n".join(runner.available_stages()))
            return 0
        if args.command == "presets":
            from fracture.pipeline import presets

            width = max(map(len, presets.names()))
            print("\n".join(f"{name:<{width}}  {presets.summary(name)}" for name in presets.names()))
            return 0
        if args.command == "compile":
            from fracture.pipeline.warmup import compile_kernels

            print(f"kernels compiled and cached in {compile_kernels(args.processes):.1f} s")
            return 0
        if args.command == "render":
            return _render(args)
        if args.command == "export":
            from fracture.pipeline.export import export_run

            print(f"wrote {export_run(args.run_dir, args.format, args.out, args.force)}")
            return 0
        if args.command == "view":
            return _view(args)
        if args.command == "sweep":
            return _sweep(args)
        if args.command == "config" and args.explain is not None:
            from fracture.pipeline.config import explain

            print(explain(args.explain))
            return 0
        if args.config is None:
            raise ConfigError("fracref config", "", "expected a config file (or --explain KEY)")
        cfg = load_config(args.config, args.overrides)
        if args.command == "config":
            sys.stdout.write(dump_config(cfg))
            return 0
        from fracture.pipeline import runner

        runner.stages_until(args.until)  # reject a bad --until before any work
        out = args.out if args.out is not None else Path("runs") / cfg.name
        done = runner.run(cfg, out, until=args.until, force=args.force, progress=not args.quiet,
                          cache=cache_from_args(args))
        manifest = layout.read_manifest(done)
        if not args.quiet:
            print(runner.timing_table(manifest))
        if manifest.get("notes"):  # what was repaired, left out or refused on the way: a user's to know, quiet or not
            print("notes:\n" + "\n".join(f"  - {note}" for note in manifest["notes"]))
        print(f"run complete: {done}  (manifest: {done / layout.MANIFEST})")
        return 0
    except (ConfigError, InputError, ResultError, StageError, RunDirectoryExists, OutputError) as exc:
        print(f"fracref: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a file the command reads or writes outside a run directory
        if exc.filename is None:
            raise
        print(f"fracref: error: {exc.filename}: {exc.strerror}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as stop:  # ours (Ctrl-C, SIGTERM), or Python's where ours was not set
        return _say_stopped(getattr(stop, "code", 130), argv, getattr(stop, "run_in_place", None))


def _start_view(run_dir: Path, camera: Path | None):
    """The view a render or the window starts from: the run's config ``view:`` section, or ``camera``'s."""
    from viewer.data import RunData
    from viewer.state import from_section, read_view_file

    from fracture.io import layout

    if camera is not None:
        return read_view_file(camera)
    run = RunData(run_dir)
    return from_section(run.config.get("view"), str(run.dir / layout.CONFIG))


def _render(args) -> int:
    from dataclasses import replace

    from viewer.media import Timing
    from viewer.request import DEFAULT_WHAT, check_request

    state = _start_view(args.run_dir, args.camera)
    flags = {"field": args.field, "axis": args.axis, "level": args.level, "cutaway": args.cutaway,
             "color_by": args.color_by, "overlay_coarse": args.overlay_coarse}
    view = replace(state.view, **{k: v for k, v in flags.items() if v is not None})
    whats = tuple(args.what or ())
    if args.frame is not None:
        if args.frame < 1:
            from fracture.errors import InputError

            raise InputError(f"--frame counts frames from 1; got {args.frame}")
        view = replace(view, frame=args.frame - 1)
    elif {"compare", "turntable"} & set(whats) and args.camera is None and view.frame == 0:
        view = replace(view, frame=-1)  # the last: the pieces apart
    timing = Timing(args.fps, args.image_seconds, args.hold)
    # the request is checked against the run before the renderer's libraries load (Open3D: seconds), so a
    # wrong flag or run directory is said at once
    request = check_request(args.run_dir, whats or None, args.width, args.height, timing, view,
                            args.turntable_seconds, args.supersample)
    from viewer.render import render

    done = render(request.run, whats or None, args.out, args.width, args.height, timing, view, args.quiet,
                  args.supersample, args.transparent, args.turntable_seconds, state.cameras)
    for what, files in done.items():
        pngs = [f for f in files if f.suffix == ".png"]
        videos = [f for f in files if f.suffix == ".mp4"]
        print(f"{what}: " + ", ".join(([f"{len(pngs)} images"] if pngs else []) + [str(v) for v in videos]
                                     + ([str(pngs[0])] if len(pngs) == 1 else [])))
    for what in DEFAULT_WHAT if not whats else ():
        if what not in done:
            print(f"{what}: not in this run (it stopped before the stage that makes it)")
    return 0


def _sweep(args) -> int:
    from fracture.errors import ConfigError
    from fracture.pipeline import runner
    from fracture.pipeline.config import load_config
    from fracture.pipeline.sweep import finished, parse_grid, run_sweep

    if not 1 <= args.jobs <= 1024:
        raise ConfigError("--jobs", "", f"got {args.jobs}, expected a number of points at once in 1..1024")
    if args.address is not None and args.backend != "ray":
        raise ConfigError("--address", "", f"got {args.address!r} with the {args.backend} backend; expected it with "
                          "--backend ray (the cluster to join)")
    cfg = load_config(args.config, args.overrides)
    grid = parse_grid(args.grid) if args.grid else cfg.sweep.grid
    runner.stages_until(args.until)
    out = args.out if args.out is not None else Path("runs") / f"{cfg.name}-sweep"
    state = run_sweep(args.config, grid, out, args.overrides, args.jobs, args.backend, args.address, args.until,
                      checked_cache_dir(args), not args.no_cache, progress=not args.quiet)
    names = finished(state)
    failed = {n: p for n, p in state["points"].items() if p["status"] == "failed"}
    if names and not args.no_sheet and (args.until is None or args.until not in ("coarse", "fields")):
        from viewer.data import read_sweep
        from viewer.render import contact_sheet

        done = read_sweep(out)
        print(f"contact sheet: {contact_sheet([p.dir for p in done], [p.label for p in done], Path(out) / 'sheet.png')}")
    print(f"sweep: {len(names)} of {len(state['points'])} points done, tables: {Path(out) / 'table.md'}, "
          f"{Path(out) / 'table.csv'}")
    for name, p in failed.items():
        print(f"fracref: error: sweep point {name}: {p['error']}", file=sys.stderr)
    return 2 if failed else 0


def _view(args) -> int:
    from fracture.errors import InputError

    for name, value in (("width", args.width), ("height", args.height)):
        if not 480 <= value <= 16384:
            raise InputError(f"view: --{name} must be a window size in pixels in 480..16384, got {value}")
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise InputError("view: no display to open a window on (DISPLAY is not set); `fracref render RUN` makes the "
                         "same pictures without one")
    from viewer.app import main as view_main  # the window's libraries (Open3D: seconds) once it can open

    return view_main(args.target, args.out, args.width, args.height, args.camera)


if __name__ == "__main__":
    sys.exit(main())

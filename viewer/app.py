"""``fracref view CONFIG_OR_RUN_DIR``: the research viewer window.

Three panels side by side (:mod:`viewer.panels`: material space, the
iterations, the animation), each an Open3D SceneWidget with its controls below
it, and a side panel (:mod:`viewer.side`) that binds the config's tunable
numbers. "Re-run" runs the pipeline in the re-run process (:mod:`viewer.rerun`)
into a new run directory (never over the shown one) while the iterations
panel follows the refinement live; errors go to a message box and the status
line. "Save config" writes YAML that reproduces the run on screen.
Screenshots (one panel or all three, chosen size) and videos (iterations or
animation) are written next to the run (:mod:`viewer.exports`). The window
composes these and holds what they share: the run, the view state, the
cameras' links, the playback clock and the hotkeys.
"""

from __future__ import annotations

import threading
import time
import traceback
from dataclasses import replace
from pathlib import Path

import numpy as np
from open3d.visualization import gui

from fracture.io import layout
from fracture.io.atomic import atomic_write_text
from fracture.errors import ConfigError, InputError, ResultError, StageError
from fracture.pipeline.config import Config
from viewer.data import RunData, SweepPoint, read_sweep
from viewer.exports import Exports, numbered
from viewer.lifetime import Lifetime
from viewer.panels import AnimationPanel, IterationsPanel, MaterialPanel, Panel
from viewer.rerun import RerunWorker
from viewer.side import SIDE_WIDTH_EM, SidePanel
from viewer.state import PANELS, ViewState, from_section, write_view_file


class Viewer:
    """The window and its state; the panels' and the side panel's handlers are methods, so scripts and
    tests drive it like a user."""

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
        # re-runs go to one child process (viewer/rerun.py), started when a parameter is first
        # edited, so that it has imported the pipeline by the re-run; a window only looked at starts none
        self.rerunner = RerunWorker()
        self.material, self.iterations, self.animation = MaterialPanel(self), IterationsPanel(self), AnimationPanel(self)
        self.panels: list[Panel] = [self.material, self.iterations, self.animation]
        for i, panel in enumerate(self.panels):
            panel.widget.set_on_mouse(self._on_mouse(i))
            panel.widget.set_on_key(self._on_key(i))
            self.window.add_child(panel.widget)
            self.window.add_child(panel.controls)
        self.side = SidePanel(self)
        self.window.add_child(self.side.widget)
        self._last_step = 0.0
        self._sync_from: int | None = None
        self._job = None  # a generator stepped on ticks (video export)
        self.exports = Exports(self)  # screenshots and videos of the panels (viewer/exports.py)
        self._worker: threading.Thread | None = None
        self._live: dict | None = None
        self._live_lock = threading.Lock()
        self.rerun_dirs: list[Path] = []
        self.errors: list[str] = []
        self.live_updates = 0  # iterations of a re-run drawn while it ran
        self.show_view(start)

    @property
    def cfg(self) -> dict:
        """The config of the run on screen, as its file holds it (the side panel's starting values)."""
        return self.run.config

    def say(self, text: str) -> None:
        self.side.say(text)

    def _layout(self, ctx) -> None:
        r = self.window.content_rect
        side_w = SIDE_WIDTH_EM * self.em
        ctrl_h = max(p.controls.calc_preferred_size(ctx, gui.Widget.Constraints()).height for p in self.panels)
        pw = (r.width - side_w) // 3
        for i, p in enumerate(self.panels):
            p.widget.frame = gui.Rect(r.x + i * pw, r.y, pw, r.height - ctrl_h)
            p.controls.frame = gui.Rect(r.x + i * pw, r.y + r.height - ctrl_h, pw, ctrl_h)
        self.side.widget.frame = gui.Rect(r.x + 3 * pw, r.y, r.width - 3 * pw, r.height)
        for p in self.panels:  # cameras fitted before the panels had a size: fit them now
            p.refit()

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
        cameras = [p.current_pose() for p in self.panels]
        self.previous_point, self.point = self.point, k
        self.load(run, keep_view=True)
        for p, pose in zip(self.panels, cameras):
            p.pose = pose
            p.place(pose)
        self.side.show_values(self.cfg)
        self.side.point_box.selected_index = k
        self.window.title = f"fracref: {self.sweep[k].name}"
        self.say(f"sweep point {k + 1} / {len(self.sweep)}: {self.sweep[k].label}")

    def flip_points(self) -> None:
        """Back to the point shown before (again: forth), to compare two points."""
        if self.sweep:
            self.show_point(self.previous_point)

    # -- loading and the cameras ---------------------------------------------------------------

    def load(self, run: RunData, keep_view: bool = False) -> None:
        """Show ``run`` in all panels (after start-up or a re-run: the last iteration and the first frame,
        unless ``keep_view``)."""
        self.run = run
        self.view = (self.view if keep_view else replace(self.view, iteration=-1, frame=0)).check(run)
        self.view = replace(self.view, iteration=int(np.clip(self.view.iteration, 0, self.iterations.count - 1)),
                            frame=int(np.clip(self.view.frame, 0, max(run.n_frames - 1, 0))))
        for p in self.panels:
            p.pose = None
            p.sync()
            p.show(run)
        for p in self.panels:
            p.draw()

    def reset_view(self, i: int | None = None) -> None:
        """Panel ``i``'s camera (every panel's by default) back to its fitted view."""
        for p in self.panels if i is None else (self.panels[i],):
            p.reset()

    def _follow(self, src: int) -> None:
        """Linked cameras: every other panel looks from the same direction, with the same up,
        at its own subject from its own fitted distance (the subjects differ in size and place)."""
        cur = self.panels[src].current_pose()
        for j, p in enumerate(self.panels):
            if j != src:
                p.look_along(cur.center - cur.eye, cur.up)

    def set_preset(self, name: str) -> None:
        """Every panel seen from the front, the side, the top or in three-quarter view
        (:data:`viewer.panels.PRESETS`), with the run's up axis up, each at its own fitted distance."""
        up = "xyz".index(self.run.up_axis)
        a, b = [k for k in range(3) if k != up]
        E = np.eye(3)
        direction, screen_up = {
            "front": (-E[a], E[up]), "side": (E[b], E[up]), "top": (E[up], E[b]),
            "iso": (E[b] - E[a] + 0.8 * E[up], E[up]),
        }[name]
        for p in self.panels:
            p.look_along(-direction, screen_up)

    # -- input and the clock ------------------------------------------------------------------------

    def _on_mouse(self, i: int):
        def handler(event):
            if self.animation.link_box.checked and event.type in (
                    gui.MouseEvent.Type.DRAG, gui.MouseEvent.Type.WHEEL, gui.MouseEvent.Type.BUTTON_UP):
                self._sync_from = i
            return gui.Widget.EventCallbackResult.IGNORED
        return handler

    def _on_key(self, i: int):
        """Hotkeys over a panel: space play/pause, arrows step, R reset the view, S screenshot, F flip between
        two sweep points."""
        def handler(event):
            if event.type != gui.KeyEvent.Type.DOWN:
                return gui.Widget.EventCallbackResult.IGNORED
            player = self.animation if i == 2 else self.iterations
            if event.key == gui.KeyName.SPACE:
                player.toggle_play()
            elif event.key in (gui.KeyName.LEFT, gui.KeyName.RIGHT):
                step = 1 if event.key == gui.KeyName.RIGHT else -1
                if player is self.animation:
                    player.set_frame(self.view.frame + step)
                else:
                    player.set_iteration(self.view.iteration + step)
            elif event.key == gui.KeyName.R:
                self.reset_view(None if self.animation.link_box.checked else i)
            elif event.key == gui.KeyName.S:
                self.exports.screenshot(self.side.shot_box.selected_text)
            elif event.key == gui.KeyName.F and self.sweep:
                self.flip_points()
            else:
                return gui.Widget.EventCallbackResult.IGNORED
            return gui.Widget.EventCallbackResult.CONSUMED
        return handler

    def _tick(self) -> bool:
        redraw = False
        if self._sync_from is not None:  # linked cameras follow the one the user moved
            self._follow(self._sync_from)
            self._sync_from = None
            redraw = True
        redraw |= self.animation.ground_from_camera()
        now = time.monotonic()
        players = [p for p in (self.iterations, self.animation) if p.playing]
        if players and now - self._last_step >= 1.0 / max(self.side.play_fps.int_value, 1):
            self._last_step = now
            for p in players:
                p.step()
            redraw = True
        with self._live_lock:
            live, self._live = self._live, None
        if live is not None:
            self.iterations.draw(live)
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
        self.rerunner.stop()

    def _on_close(self) -> bool:
        if self._worker is not None and self._worker.is_alive():
            self.say("a re-run is still going; it ends with the window")
        self.rerunner.close()
        return True

    # -- re-run and config ---------------------------------------------------------------------------

    def checked_config(self) -> tuple[Config, str]:
        """The side panel's config, validated as ``fracref run`` would read it, and its YAML."""
        from fracture.pipeline.config import check_config, dump_config

        cfg = self.side.edited(self.cfg)
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
        """Run the pipeline with the side panel's parameters in the re-run process, into a new run
        directory; a thread of the window relays its progress."""
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
            import queue as queue_mod

            worker = self.rerunner
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
        for panel, name in zip(self.panels, PANELS):
            if state.cameras.get(name) is not None:
                panel.set_pose(state.cameras[name])

    def view_state(self) -> ViewState:
        """What the panels show and every panel's camera as the user left it."""
        return ViewState(self.view, {name: p.current_pose() for p, name in zip(self.panels, PANELS)})

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


__all__ = ["Viewer", "main", "open_target"]

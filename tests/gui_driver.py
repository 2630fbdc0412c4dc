"""Drives the viewer window like a user, for tests/test_viewer.py (run under Xvfb, one scenario per process).

Usage: python gui_driver.py SCENARIO RUN_DIR OUT_DIR. Writes OUT_DIR/result.json
and PNGs; exits 0 when the scenario ran, 3 when the watchdog fired.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from pathlib import Path

WATCHDOG_SECONDS = 150


def _watchdog():
    time.sleep(WATCHDOG_SECONDS)
    print("watchdog: the window stopped responding", flush=True)
    os._exit(3)


def _xdotool(app, *args) -> None:
    """Run one xdotool command while the window keeps handling its events."""
    import subprocess

    p = subprocess.Popen(["xdotool", *map(str, args)])
    while p.poll() is None:
        app.run_one_tick()
    for _ in range(5):
        app.run_one_tick()


def _origin(app, v) -> tuple[int, int]:
    import subprocess

    wid = subprocess.run(["xdotool", "search", "--name", v.window.title], capture_output=True,
                         text=True).stdout.split()[0]
    geo = subprocess.run(["xdotool", "getwindowgeometry", wid], capture_output=True, text=True).stdout
    x, y = geo.split("Position: ")[1].split()[0].split(",")
    return int(x), int(y)


def _drag(app, v, origin, i: int, dx: int = 120, dy: int = 40, button: int = 1) -> None:
    """A real mouse drag from the middle of panel ``i``."""
    f = v.panels[i].widget.frame
    x, y = origin[0] + f.x + f.width // 2, origin[1] + f.y + f.height // 2
    _xdotool(app, "mousemove", x, y)
    _xdotool(app, "mousedown", button)
    for k in range(1, 9):
        _xdotool(app, "mousemove", x + dx * k // 8, y + dy * k // 8)
    _xdotool(app, "mouseup", button)


def _panel_content(app, v, i: int) -> dict:
    """What panel ``i`` shows with its camera now, at its size: share of non-background pixels and
    the content's centre as a fraction of the panel (0.5, 0.5 is the middle)."""
    import numpy as np

    f = v.panels[i].widget.frame
    img = np.asarray(app.render_to_image(v.panels[i].scene, f.width, f.height))[..., :3].astype(int)
    mask = np.abs(img - img[0, 0]).sum(axis=2) > 30
    ys, xs = np.nonzero(mask)
    centre = [float(xs.mean() / f.width), float(ys.mean() / f.height)] if len(xs) else [None, None]
    return {"share": float(mask.mean()), "centre": centre}


def _cameras(v) -> list:
    import numpy as np

    return [np.concatenate([np.asarray(sw.scene.camera.get_model_matrix()).ravel(),
                            np.asarray(sw.scene.camera.get_projection_matrix()).ravel()]).tolist()
            for sw in (p.widget for p in v.panels)]


def navigate(app, v, out) -> dict:
    """Drags in each panel, then with linked cameras; exports; a preset; the R key."""
    res: dict = {"initial": [_panel_content(app, v, i) for i in range(3)]}
    origin = _origin(app, v)
    res["after_drag"] = []
    for i in range(3):
        _drag(app, v, origin, i)
        res["after_drag"].append(_panel_content(app, v, i))
    res["moved"] = _cameras(v)
    v.reset_view()
    v.animation.link_box.checked = True
    _drag(app, v, origin, 1, dx=-150, dy=60)
    for _ in range(5):
        app.run_one_tick()
    res["linked"] = [_panel_content(app, v, i) for i in range(3)]
    import numpy as np

    M = [np.asarray(sw.scene.camera.get_model_matrix()) for sw in (p.widget for p in v.panels)]
    res["linked_forward"] = [(-m[:3, 2]).tolist() for m in M]
    before = _cameras(v)
    v.side.export_w.int_value, v.side.export_h.int_value, v.side.export_fps.int_value = 640, 360, 5
    res["screenshot"] = str(v.exports.screenshot("all panels", out / "shot.png"))
    v.exports.screenshot("iterations", out / "shot_it.png")
    v.exports.export_video("iterations", out / "it.mp4")
    while v._job is not None:
        app.run_one_tick()
    res["cameras_before_export"], res["cameras_after_export"] = before, _cameras(v)
    res["after_export"] = [_panel_content(app, v, i) for i in range(3)]
    v.animation.link_box.checked = False
    _drag(app, v, origin, 2)
    f = v.panels[2].widget.frame
    _xdotool(app, "mousemove", origin[0] + f.x + f.width // 2, origin[1] + f.y + f.height // 2)
    _xdotool(app, "key", "r")
    for j in (0, 1):  # the key reset panel 2 only
        v.reset_view(j)
    res["after_reset_key"], res["fresh"] = _cameras(v), _fresh(app, v)
    v.set_preset("top")
    res["top"] = [_panel_content(app, v, i) for i in range(3)]
    return res


def views(app, v, out) -> dict:
    """The layout at the default size, Save view read back by a second window, Save config, the
    comparison and transparent screenshots, then the window left idle under app.run()."""
    from dataclasses import asdict

    from viewer.state import read_view_file

    res: dict = {}
    r = v.window.content_rect
    res["content"] = [r.x, r.y, r.width, r.height]
    widgets = {"fps": v.side.export_fps, "hold": v.side.export_hold, "supersample": v.side.export_scale,
               "transparent": v.side.transparent_box, "shot": v.side.shot_box, "play": v.side.play_fps, "status": v.side.status,
               "cutaway": v.material.cutaway_box, "preset": v.animation.preset_box, "link": v.animation.link_box,
               "slice_bar_high": v.material.bar[3], "surface_bar_high": v.iterations.bar[3], "colour": v.iterations.color_box}
    res["frames"] = {k: [w.frame.x, w.frame.y, w.frame.width, w.frame.height] for k, w in widgets.items()}
    res["side"] = [v.side.widget.frame.x, v.side.widget.frame.y, v.side.widget.frame.width, v.side.widget.frame.height]
    res["panels"] = [[c.frame.x, c.frame.y, c.frame.width, c.frame.height] for c in (p.controls for p in v.panels)]
    # a view of its own: another slice, iteration, frame and dragged cameras
    v.material.set_offset(0.3)
    v.iterations.set_iteration(1)
    v.animation.set_frame(v.run.n_frames - 1)
    v.material.set_cutaway(True)
    origin = _origin(app, v)
    for i in range(3):
        _drag(app, v, origin, i, dx=-90, dy=30)
    saved_view = v.save_view(out / "view.yaml")
    saved_config = v.save_config(out / "config_saved.yaml")
    res["cameras_first"], first = _cameras(v), asdict(v.view)
    # elsewhere, then back to the saved view (as `fracref view --camera FILE` starts)
    v.reset_view()
    v.material.set_offset(0.7)
    v.iterations.set_iteration(0)
    v.material.set_cutaway(False)
    v.show_view(read_view_file(saved_view))
    for _ in range(10):
        app.run_one_tick()
    res["cameras_second"] = _cameras(v)
    res["views"] = [first, asdict(v.view)]
    res["saved_config"] = str(saved_config)
    v.side.export_w.int_value, v.side.export_h.int_value = 640, 360
    res["compare"] = str(v.exports.screenshot("coarse vs refined", out / "compare.png"))
    v.side.transparent_box.checked = True
    v.side.export_scale.int_value = 2
    res["transparent"] = str(v.exports.screenshot("animation", out / "transparent.png"))
    v.side.transparent_box.checked = False
    v.side.export_scale.int_value = 1
    res["errors"] = list(v.errors)

    # idle: the real event loop with nothing to do, its CPU time against the wall clock's
    def measure():
        time.sleep(3.0)  # the loop settles
        c0, w0 = time.process_time(), time.monotonic()
        time.sleep(4.0)
        res["idle_cpu"] = (time.process_time() - c0) / (time.monotonic() - w0)
        app.post_to_main_thread(v.window, app.quit)
    threading.Thread(target=measure, daemon=True).start()
    app.run()  # the window is gone when it returns
    return res


def _fresh(app, v) -> list:
    v.reset_view()
    for _ in range(3):
        app.run_one_tick()
    return _cameras(v)


def sweep_points(app, v, out, shot) -> dict:
    """A sweep: the point chosen in the list, then F over a panel (a real key press) flips back and forth."""
    import numpy as np

    r = {"points": [str(p.dir) for p in v.sweep], "shown": [str(v.run.dir)], "title": [v.window.title]}
    r["shots"] = [shot(1, "point0")]
    cameras = [v.panels[i].current_pose() for i in range(3)]
    v.side.point_box.selected_index = 1
    v.show_point(1)  # what choosing the second item does (setting the index does not call the handler)
    for _ in range(5):
        app.run_one_tick()
    r["shown"].append(str(v.run.dir))
    r["title"].append(v.window.title)
    r["shots"].append(shot(1, "point1"))
    r["stress_weight_edit"] = v.side.edits["psi.stress_weight"].double_value
    r["cameras_kept"] = all(np.allclose(a.eye, b.eye, atol=1e-5) and np.allclose(a.center, b.center, atol=1e-5)
                            for a, b in zip(cameras, [v.panels[i].current_pose() for i in range(3)]))
    origin = _origin(app, v)
    f = v.panels[1].widget.frame
    _xdotool(app, "mousemove", origin[0] + f.x + f.width // 2, origin[1] + f.y + f.height // 2)
    _xdotool(app, "click", 1)  # the panel takes the keys
    for _ in range(2):
        _xdotool(app, "key", "f")
        for _ in range(5):
            app.run_one_tick()
        r["shown"].append(str(v.run.dir))
    r["selected"] = v.side.point_box.selected_index
    return r


def main() -> None:
    scenario, run_dir, out = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
    threading.Thread(target=_watchdog, daemon=True).start()
    import imageio.v3 as iio

    from viewer.lazy_open3d import defer_open3d_ml

    defer_open3d_ml()  # as `fracref view` starts
    from open3d.visualization import gui

    from viewer.app import Viewer
    from viewer.data import RunData, read_sweep

    app = gui.Application.instance
    app.initialize()
    sweep = read_sweep(run_dir) if (run_dir / "sweep.json").is_file() else None
    size = (1800, 900) if scenario == "views" else (1000, 600)  # views: the default size; else small: quick to draw
    v = Viewer(RunData(sweep[0].dir) if sweep else RunData(run_dir), *size, sweep=sweep)
    for _ in range(10):
        app.run_one_tick()
    out.mkdir(parents=True, exist_ok=True)
    result: dict = {"errors": v.errors}

    def shot(i, name):
        img = v.exports.panel_image(i, 480, 360)
        iio.imwrite(out / f"{name}.png", img)
        return str(out / f"{name}.png")

    if scenario == "panels":
        # each camera against one fitted afresh to its panel's shape now (before the first layout, the
        # panels had no size and the cameras were fitted to a square)
        shown = [p.camera() for p in v.panels]
        for p in v.panels:
            p.pose = None
        result["camera_refit"] = [[a.eye.tolist(), p.camera().eye.tolist()] for a, p in zip(shown, v.panels)]
        result["initial"] = [shot(i, f"panel{i}") for i in range(3)]
        v.iterations.set_iteration(1)
        result["iteration1"] = shot(1, "iteration1")
        v.animation.set_frame(v.run.n_frames - 1)
        result["frame_last"] = shot(2, "frame_last")
        v.material.set_offset(0.2)
        result["offset"] = shot(0, "offset")
        v.material.set_field("zeta")
        result["zeta"] = shot(0, "zeta")
        v.side.export_w.int_value, v.side.export_h.int_value, v.side.export_fps.int_value = 640, 360, 5
        v.side.export_seconds.double_value, v.side.export_hold.double_value = 0.4, 0.6  # 2 video frames each, 3 more at the end
        result["screenshot"] = str(v.exports.screenshot("all panels", out / "window_all.png"))
        v.exports.export_video("animation", out / "window_animation.mp4")
        while v._job is not None:
            app.run_one_tick()
        result["video"] = str(out / "window_animation.mp4")
        from viewer.media import frame_counts

        # the animation at its own frame rate in a 5 fps video, the last frame held 0.6 s (3 frames)
        result["frames"] = sum(frame_counts(v.run.n_frames, v.run.seconds_per_frame, 5)) + 3
    elif scenario == "navigate":
        result.update(navigate(app, v, out))
    elif scenario == "views":
        result.update(views(app, v, out))
    elif scenario == "sweep":
        result.update(sweep_points(app, v, out, shot))
    elif scenario == "rerun":
        result["worker_at_open"] = v.rerunner.alive  # a window only looked at starts no re-run process
        before = v.run.iteration(len(v.run.iterations) - 1)
        v.side.edits["psi.stress_weight"].double_value = 0.0
        v.side.edits["seed"].int_value = v.side.edits["seed"].int_value + 1
        # a refinement of a few seconds, so that its iterations reach the window while it runs
        v.side.edits["refine.iterations"].int_value = 40
        v.side.edits["refine.max_triangles"].int_value = 120000
        v.rerun()
        # the ticks while the re-run runs; the one that loads its result and the first renders of
        # that (seconds under Xvfb's software renderer, as when a window opens) come after it
        ticks = 0
        while v._worker is not None and v._worker.is_alive():
            app.run_one_tick()
            ticks += not v.rerun_dirs
        for _ in range(20):  # the finished run arrives through the main thread's queue
            app.run_one_tick()
        after = v.run.iteration(len(v.run.iterations) - 1)
        result.update(ticks=ticks, live_updates=v.live_updates,
                      rerun_dirs=[str(p) for p in v.rerun_dirs], shown=str(v.run.dir),
                      same_surface=bool(before.V.shape == after.V.shape and (before.V == after.V).all()),
                      stress_weight=v.cfg["psi"]["stress_weight"])
        result["panel"] = shot(1, "after_rerun")
        saved = v.save_config(out / "saved.yaml")
        result["saved"] = str(saved)
        v.side.edits["refine.step"].double_value = -1.0  # invalid: the window reports it
        v.rerun()
        result["errors"] = v.errors
    (out / "result.json").write_text(json.dumps(result, indent=1))
    print("done", flush=True)
    sys.stdout.flush()
    os._exit(0)


if __name__ == "__main__":
    main()

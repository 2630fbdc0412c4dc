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


def main() -> None:
    scenario, run_dir, out = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
    threading.Thread(target=_watchdog, daemon=True).start()
    import imageio.v3 as iio
    from open3d.visualization import gui

    from viewer.app import Viewer
    from viewer.data import RunData

    app = gui.Application.instance
    app.initialize()
    v = Viewer(RunData(run_dir), 1500, 800)
    for _ in range(10):
        app.run_one_tick()
    out.mkdir(parents=True, exist_ok=True)
    result: dict = {"errors": v.errors}

    def shot(i, name):
        img = v.panel_image(i, 480, 360)
        iio.imwrite(out / f"{name}.png", img)
        return str(out / f"{name}.png")

    if scenario == "panels":
        # each camera against one fitted afresh to its panel's shape now (before the first layout, the
        # panels had no size and the cameras were fitted to a square)
        shown = list(v.poses)
        v.poses = [None, None, None]
        result["camera_refit"] = [[a.eye.tolist(), v._pose(i).eye.tolist()] for i, a in enumerate(shown)]
        result["initial"] = [shot(i, f"panel{i}") for i in range(3)]
        v.set_iteration(1)
        result["iteration1"] = shot(1, "iteration1")
        v.set_frame(v.run.n_frames - 1)
        result["frame_last"] = shot(2, "frame_last")
        v.set_offset(0.2)
        result["offset"] = shot(0, "offset")
        v.set_field("zeta")
        result["zeta"] = shot(0, "zeta")
        v.export_w.int_value, v.export_h.int_value, v.export_fps.int_value = 640, 360, 5
        result["screenshot"] = str(v.screenshot("all panels", out / "window_all.png"))
        v.export_video("animation", out / "window_animation.mp4")
        while v._job is not None:
            app.run_one_tick()
        result["video"] = str(out / "window_animation.mp4")
        result["frames"] = v.run.n_frames
    elif scenario == "rerun":
        before = v.run.iteration(len(v.run.iterations) - 1)
        v.edits["psi.stress_weight"].double_value = 0.0
        v.edits["seed"].int_value = v.edits["seed"].int_value + 1
        # a refinement of a few seconds, so that its iterations reach the window while it runs
        v.edits["refine.iterations"].int_value = 40
        v.edits["refine.max_triangles"].int_value = 60000
        v.rerun()
        # the ticks while the re-run runs; the one that loads its result and the first renders of
        # that (seconds under Xvfb's software renderer, as when a window opens) come after it
        gaps, last = [], time.monotonic()
        while v._worker is not None and v._worker.is_alive():
            app.run_one_tick()
            now = time.monotonic()
            if not v.rerun_dirs:
                gaps.append(now - last)
            last = now
        for _ in range(20):  # the finished run arrives through the main thread's queue
            app.run_one_tick()
        after = v.run.iteration(len(v.run.iterations) - 1)
        result.update(max_tick_gap=max(gaps) if gaps else 0.0, ticks=len(gaps), live_updates=v.live_updates,
                      rerun_dirs=[str(p) for p in v.rerun_dirs], shown=str(v.run.dir),
                      same_surface=bool(before.V.shape == after.V.shape and (before.V == after.V).all()),
                      stress_weight=v.cfg["psi"]["stress_weight"])
        result["panel"] = shot(1, "after_rerun")
        saved = v.save_config(out / "saved.yaml")
        result["saved"] = str(saved)
        v.edits["refine.step"].double_value = -1.0  # invalid: the window reports it
        v.rerun()
        result["errors"] = v.errors
    (out / "result.json").write_text(json.dumps(result, indent=1))
    print("done", flush=True)
    sys.stdout.flush()
    os._exit(0)


if __name__ == "__main__":
    main()

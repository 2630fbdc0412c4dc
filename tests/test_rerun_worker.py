"""The viewer's re-run process: one child serves re-run after re-run, reports errors without dying, and is
started again when it died (no window needed: the worker is plain multiprocessing)."""

import json
import os
import queue
import signal

import pytest

from fracture.pipeline.config import load_config
from viewer.rerun import RerunWorker


def events_until_end(worker, timeout=300.0):
    """The events of one job, up to its ``done`` or ``error``."""
    seen = []
    while True:
        try:
            event, data = worker.events.get(timeout=timeout)
        except queue.Empty:
            pytest.fail(f"no end of the job after {timeout} s; events so far: {[e for e, _ in seen]}")
        seen.append((event, data))
        if event in ("done", "error"):
            return seen


def test_one_child_serves_re_runs_in_turn_and_survives_a_failed_one(tmp_path, small_config):
    worker = RerunWorker()
    worker.start()
    try:
        pid = worker._proc.pid
        cfg = load_config(small_config, ["refine.iterations=3"])
        worker.submit(cfg, str(tmp_path / "a"))
        first = events_until_end(worker)
        assert first[-1][0] == "done" and (tmp_path / "a" / "manifest.json").is_file()
        assert ("stage", {"name": "refine"}) in first and any(e == "iteration" for e, _ in first)
        # a psi change: the same child, the coarse stage from the stage cache
        cfg2 = load_config(small_config, ["refine.iterations=3", "psi.stress_weight=1.5"])
        worker.submit(cfg2, str(tmp_path / "b"))
        assert events_until_end(worker)[-1][0] == "done" and worker._proc.pid == pid
        manifest = json.loads((tmp_path / "b" / "manifest.json").read_text())
        assert manifest["stages"]["coarse"]["cache"] == "reused"
        # a run that fails (its output directory is a file) is reported, and the child goes on
        (tmp_path / "c").write_text("in the way")
        worker.submit(cfg, str(tmp_path / "c"))
        end = events_until_end(worker)[-1]
        assert end[0] == "error" and worker.alive and worker._proc.pid == pid
    finally:
        worker.close(timeout=10)
    assert not worker.alive


def test_a_child_that_died_is_started_again_for_the_next_re_run(tmp_path, small_config):
    worker = RerunWorker()
    worker.start()
    try:
        os.kill(worker._proc.pid, signal.SIGKILL)
        worker._proc.join(10)
        assert not worker.alive and worker.exitcode == -signal.SIGKILL
        worker.submit(load_config(small_config, ["refine.iterations=2"]), str(tmp_path / "a"))
        assert worker.alive
        assert events_until_end(worker)[-1][0] == "done" and (tmp_path / "a" / "manifest.json").is_file()
    finally:
        worker.close(timeout=10)


def test_the_child_ends_when_the_windows_process_is_gone(tmp_path):
    """A window's process that ends without closing the worker (killed, or os._exit) leaves no child."""
    import subprocess
    import sys
    import time

    script = tmp_path / "parent.py"
    script.write_text(
        "import os, sys\n"
        "from viewer.rerun import RerunWorker\n"
        "if __name__ == '__main__':\n"
        "    w = RerunWorker(); w.start()\n"
        "    print(w._proc.pid, flush=True)\n"
        "    os._exit(0)\n")
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120,
                         cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    child = int(out.stdout.split()[0])
    for _ in range(300):
        try:
            os.kill(child, 0)
        except ProcessLookupError:
            return
        time.sleep(0.1)
    os.kill(child, signal.SIGKILL)
    pytest.fail("the re-run child outlived its parent by 30 s")


def test_the_childs_stop_inside_a_compiler_callback_is_taken_after_it(monkeypatch):
    """The re-run child's SIGTERM handler, as the command line's: inside a callback from llvmlite's C code
    (a kernel compiled for the first time in the child, where an exception would be dropped and the child
    killed with its staging left) it sends the signal again a moment later; elsewhere it unwinds."""
    import sys
    import time

    from viewer import rerun

    sent = []
    monkeypatch.setattr(os, "kill", lambda pid, sig: sent.append((pid, sig)))
    namespace = {"sys": sys}
    exec(compile("def callback():\n    return sys._getframe()\n",
                 "/venv/site-packages/llvmlite/binding/executionengine.py", "exec"), namespace)
    rerun._cut_short(signal.SIGTERM, namespace["callback"]())  # returns: no exception inside the callback
    for _ in range(100):
        if sent:
            break
        time.sleep(0.02)
    assert sent == [(os.getpid(), signal.SIGTERM)]
    with pytest.raises(KeyboardInterrupt):
        rerun._cut_short(signal.SIGTERM, sys._getframe())

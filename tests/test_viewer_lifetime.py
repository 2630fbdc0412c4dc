"""The viewer's process ends: on SIGINT and SIGTERM (a real window under its own Xvfb), when its X server
is killed under it, and its re-run child with it; every file of the run stays as it was."""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import CONFIGS

from fracture.pipeline import runner
from fracture.pipeline.config import load_config

# a small run: a few seconds to make, a window that opens quickly
RUN_OVERRIDES = ["input.frames=4", "refine.max_triangles=2000", "refine.iterations=3", "grid.resolution=24",
                 "animate.check_samples=1000"]
# Seconds the viewer may take to end after a signal or after its display went away.
ENDS_WITHIN = 5.0
# Seconds a window may take to appear (software rendering under Xvfb on a loaded machine).
OPENS_WITHIN = 180.0



@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("lifetime") / "jello"
    runner.run(load_config(CONFIGS / "jello.yaml", RUN_OVERRIDES), out, progress=False)
    return out


def fingerprint(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha1(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


class Xvfb:
    """A private X server on a free display (``-displayfd``: the server picks the number and tells it)."""

    def __init__(self):
        missing = [tool for tool in ("Xvfb", "xdotool") if shutil.which(tool) is None]
        if missing:
            pytest.fail(f"{' and '.join(missing)} missing: `make system-deps` installs them")
        read, write = os.pipe()
        self.proc = subprocess.Popen(["Xvfb", "-displayfd", str(write), "-screen", "0", "1280x1024x24",
                                      "-nolisten", "tcp"], pass_fds=(write,), stderr=subprocess.DEVNULL)
        os.close(write)
        with os.fdopen(read) as f:
            self.display = f":{f.readline().strip()}"

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(10)


@pytest.fixture
def xserver():
    server = Xvfb()
    yield server
    server.kill()


def open_viewer(run_dir: Path, display: str) -> subprocess.Popen:
    """``fracref view`` on ``display``, once its window is there."""
    env = {**os.environ, "DISPLAY": display}
    proc = subprocess.Popen([sys.executable, "-m", "fracref", "view", str(run_dir), "--width", "1024",
                             "--height", "640"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + OPENS_WITHIN
    while time.monotonic() < deadline:
        found = subprocess.run(["xdotool", "search", "--name", "^fracref: "], env=env, capture_output=True,
                               text=True)
        if found.stdout.strip():
            time.sleep(1.0)  # its first frames
            return proc
        if proc.poll() is not None:
            pytest.fail(f"the viewer ended before its window opened: {proc.communicate()[1][-2000:]}")
        time.sleep(0.5)
    proc.kill()
    pytest.fail(f"no viewer window within {OPENS_WITHIN:g} s")


def ended(proc: subprocess.Popen, within: float) -> tuple[int, str]:
    try:
        _, err = proc.communicate(timeout=within)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        pytest.fail(f"the viewer was still running {within:g} s later")
    return proc.returncode, err


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_closes_the_window_and_ends_the_viewer(sig, run_dir, xserver):
    before = fingerprint(run_dir)
    proc = open_viewer(run_dir, xserver.display)
    proc.send_signal(sig)
    code, err = ended(proc, ENDS_WITHIN)
    assert code == 128 + sig, err[-2000:]
    assert f"{signal.Signals(sig).name} received; closing the window" in err
    assert fingerprint(run_dir) == before


def test_the_viewer_ends_when_its_display_goes_away(run_dir, xserver):
    before = fingerprint(run_dir)
    proc = open_viewer(run_dir, xserver.display)
    xserver.kill()
    code, err = ended(proc, ENDS_WITHIN)
    assert code != 0
    assert fingerprint(run_dir) == before


def test_stopping_the_rerun_child_ends_it_mid_run_and_leaves_no_run_behind(tmp_path):
    from viewer.rerun import RerunWorker

    worker = RerunWorker()
    cfg = load_config(CONFIGS / "jello.yaml", ["refine.max_triangles=100000", "refine.snapshots=false"])
    out = tmp_path / "rerun"
    worker.submit(cfg, str(out))
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:  # until the run has begun (its first stage reported)
        event, _ = worker.events.get(timeout=deadline - time.monotonic())
        if event == "stage":
            break
    worker.stop(timeout=0.5)
    assert not worker.alive and worker.exitcode is not None
    assert not out.exists() and not list(tmp_path.glob(".rerun.partial-*"))

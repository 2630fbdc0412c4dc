"""The viewer's process ends: on SIGINT and SIGTERM (a real window under its own Xvfb), when its X server
is killed under it, and its re-run child with it; every file of the run stays as it was."""

from __future__ import annotations

import hashlib
import signal
import subprocess
import time
from pathlib import Path

import pytest
from conftest import CONFIGS
from xserver import Xvfb, open_viewer

from fracture.pipeline import runner
from fracture.pipeline.config import load_config

# a small run: a few seconds to make, a window that opens quickly
RUN_OVERRIDES = ["input.frames=4", "refine.max_triangles=2000", "refine.iterations=3", "grid.resolution=24",
                 "animate.check_samples=1000"]
# Seconds the viewer may take to end after a signal or after its display went away: a hang, not a speed (a
# window busy with its first software-rendered frames on a loaded machine took over 5 s)
ENDS_WITHIN = 60.0


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("lifetime") / "jello"
    runner.run(load_config(CONFIGS / "jello.yaml", RUN_OVERRIDES), out, progress=False)
    return out


def fingerprint(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha1(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture
def xserver():
    server = Xvfb()
    yield server
    server.kill()


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

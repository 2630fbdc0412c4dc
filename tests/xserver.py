"""A private X server for the window tests, and a viewer opened on it (used by tests/test_viewer_lifetime.py
and tests/test_readme.py)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

# Seconds a window may take to appear (software rendering under Xvfb on a loaded machine).
OPENS_WITHIN = 180.0


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


def wait_for_window(proc: subprocess.Popen, display: str) -> None:
    """Return once a window titled ``fracref: ...`` is on ``display`` (fail if ``proc`` ends first)."""
    env = {**os.environ, "DISPLAY": display}
    deadline = time.monotonic() + OPENS_WITHIN
    while time.monotonic() < deadline:
        found = subprocess.run(["xdotool", "search", "--name", "^fracref: "], env=env, capture_output=True,
                               text=True)
        if found.stdout.strip():
            time.sleep(1.0)  # its first frames
            return
        if proc.poll() is not None:
            pytest.fail(f"the viewer ended before its window opened: {proc.communicate()[1][-2000:]}")
        time.sleep(0.5)
    proc.kill()
    pytest.fail(f"no viewer window within {OPENS_WITHIN:g} s")


def open_viewer(run_dir: Path, display: str) -> subprocess.Popen:
    """``fracref view`` on ``display``, once its window is there."""
    env = {**os.environ, "DISPLAY": display}
    proc = subprocess.Popen([sys.executable, "-m", "fracref", "view", str(run_dir), "--width", "1024",
                             "--height", "640"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_for_window(proc, display)
    return proc

"""Every command in the README runs as written: the tour, in order, from a fresh working directory that
has the project's configs and environments (``make demo`` and ``make test`` are what CI itself runs).

``fracref view`` lines open a real window on a private X server and are closed with Ctrl-C (SIGINT)
once the window is there; every other line must exit 0.
"""

from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess

import pytest
from conftest import REPO
from xserver import Xvfb, wait_for_window

README = REPO / "README.md"


def readme_commands() -> list[str]:
    """The command lines of the README's ``sh`` blocks (comments dropped), in order."""
    blocks = re.findall(r"```sh\n(.*?)```", README.read_text(encoding="utf-8"), re.S)
    lines = [line.split("  #")[0].strip() for block in blocks for line in block.splitlines()]
    return [line for line in lines if line and not line.startswith("#")]


def test_the_readme_is_short_and_its_commands_are_known():
    assert len(README.read_text(encoding="utf-8").splitlines()) <= 250
    commands = readme_commands()
    assert commands[:2] == ["make demo", "make test"]
    makefile = (REPO / "Makefile").read_text(encoding="utf-8")
    assert all(re.search(rf"^{c.split()[1]}:", makefile, re.M) for c in commands[:2])
    assert any(" view " in c for c in commands) and any(" export " in c for c in commands)


@pytest.mark.slow
def test_the_tour_runs_as_written(tmp_path):
    for name in ("configs", ".venv", ".venv-blender"):
        (tmp_path / name).symlink_to(REPO / name)
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    env["FRACREF_CACHE_DIR"] = str(tmp_path / "cache")
    for line in readme_commands()[2:]:
        if " view " in line:
            server = Xvfb()
            try:
                proc = subprocess.Popen(shlex.split(line), cwd=tmp_path, env={**env, "DISPLAY": server.display},
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                wait_for_window(proc, server.display)
                proc.send_signal(signal.SIGINT)  # Ctrl-C at the terminal
                _, err = proc.communicate(timeout=30)
                assert proc.returncode == 130, f"{line}: {err[-2000:]}"
            finally:
                server.kill()
            continue
        done = subprocess.run(shlex.split(line), cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
        assert done.returncode == 0, f"{line}:\n{done.stderr[-3000:]}"
        if "bpy" in line:
            assert int(re.search(r"(\d+) objects", done.stdout).group(1)) >= 2  # the pieces, in Blender
    assert (tmp_path / "runs/tour/manifest.json").is_file()
    assert list((tmp_path / "runs/tour/renders").glob("*.mp4"))
    assert (tmp_path / "runs/tour-sweep/sweep.json").is_file()

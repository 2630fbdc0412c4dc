"""The benchmark scripts meet a wrong ``--set`` or a failed scene process with one line, not a traceback or a
wait that never ends."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.mark.parametrize("script, scene", [("bench_refine.py", "branch"), ("fidelity.py", "example")])
def test_a_wrong_override_ends_the_benchmark_with_the_loaders_line(script, scene):
    run = subprocess.run([sys.executable, str(BENCHMARKS / script), "--scenes", scene, "--set", "refine.band=-3"],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 1
    assert run.stderr.strip() == "error: --set refine.band=-3: refine.band: got -3 (int), expected a number in [1, 200]"
    assert run.stdout == ""  # nothing measured, no process started


def _fails(name, queue):
    raise RuntimeError(f"no result for {name}")


def test_a_scene_process_that_ends_without_a_result_ends_the_benchmark(monkeypatch):
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    from scenes import in_processes

    with pytest.raises(SystemExit, match="the process of scene 'jello' ended without a result \\(exit code 1\\)"):
        list(in_processes(_fails, ["jello"]))

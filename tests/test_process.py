"""Process set-up: explicit, and importing the package changes nothing."""

import contextlib
import os
import subprocess
import sys
from pathlib import Path

import pytest


def test_numba_caches_of_changed_sources_are_cleared(tmp_path):
    from fracture.refine import clear_stale_numba_cache

    (tmp_path / "a.py").write_text("import numba\nx = 1\n")
    (tmp_path / "b.py").write_text("y = 1\n")  # no numba: its changes leave the cache alone
    (tmp_path / "__pycache__").mkdir()
    old = tmp_path / "__pycache__" / "a.f-1.py311.nbi"
    old.write_bytes(b"stale")
    assert clear_stale_numba_cache(tmp_path) and not old.exists()  # no record of the sources: cleared
    fresh = tmp_path / "__pycache__" / "a.f-1.py311.1.nbc"
    fresh.write_bytes(b"compiled from x = 1")
    assert not clear_stale_numba_cache(tmp_path) and fresh.exists()  # same sources: kept
    (tmp_path / "b.py").write_text("y = 2\n")
    assert not clear_stale_numba_cache(tmp_path) and fresh.exists()
    (tmp_path / "a.py").write_text("import numba\nx = 2\n")
    assert clear_stale_numba_cache(tmp_path) and not fresh.exists()


def test_importing_the_package_changes_nothing(tmp_path):
    """Importing every module leaves the numba cache and the allocator alone (only
    :func:`fracture.process.prepare_process` touches them)."""
    code = """
import importlib, pkgutil, sys, os, pathlib
import fracture, fields, viewer
import fracture.refine as r
cache = pathlib.Path(r.__file__).parent / "__pycache__"
before = sorted(p.name for p in cache.glob("*.nb[ic]")) if cache.exists() else []
stamp = (cache / "numba-sources.sha1")
stamp_before = stamp.read_bytes() if stamp.exists() else None
for pkg in (fracture, fields, viewer):
    for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
        if not m.name.endswith("__main__"):
            importlib.import_module(m.name)
import fracture.allocator as a
after = sorted(p.name for p in cache.glob("*.nb[ic]")) if cache.exists() else []
assert before == after, "import changed the numba cache"
assert (stamp.read_bytes() if stamp.exists() else None) == stamp_before
assert not a._done, "import changed the allocator"
print("ok")
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]


def test_library_messages_reach_the_log_only_when_the_application_asks(tmp_path, small_config):
    """The library logs to the ``fracture`` logger (a NullHandler of its own, no output by default);
    ``fracref --log-level info`` shows the stages' messages on stderr."""
    run = lambda *level: subprocess.run(  # noqa: E731
        [sys.executable, "-m", "fracref", *level, "run", str(small_config), "--out", str(tmp_path / "run"),
         "--force", "--quiet", "--until", "fields"], capture_output=True, text=True)
    quiet = run()
    assert quiet.returncode == 0 and "fracture.pipeline.runner" not in quiet.stderr
    told = run("--log-level", "info")
    assert told.returncode == 0, told.stderr[-2000:]
    assert "fracture.pipeline.runner: coarse: started" in told.stderr
    assert "fracture.pipeline.runner: fields: done in" in told.stderr
    code = "import logging, fracture; print(logging.getLogger().handlers, logging.getLogger('fracture').handlers)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True).stdout
    assert out.startswith("[] [<NullHandler")


def test_a_change_in_one_compiled_package_clears_the_caches_of_both(tmp_path):
    """The refinement's kernels call the mesh package's: a change there makes both caches stale."""
    from fracture.refine import clear_stale_numba_cache

    refine, mesh = tmp_path / "refine", tmp_path / "mesh"
    for pkg in (refine, mesh):
        (pkg / "__pycache__").mkdir(parents=True)
        (pkg / "k.py").write_text("import numba\nx = 1\n")
    clear_stale_numba_cache([refine, mesh])
    compiled = refine / "__pycache__" / "collide.f-1.py311.1.nbc"
    compiled.write_bytes(b"machine code calling mesh.k")
    assert not clear_stale_numba_cache([refine, mesh]) and compiled.exists()
    (mesh / "k.py").write_text("import numba\nx = 2\n")
    assert clear_stale_numba_cache([refine, mesh]) and not compiled.exists()


def test_the_kernel_sources_are_parsed_again_only_when_a_module_changes(tmp_path, monkeypatch):
    """The stamp keeps the digest of every module beside the sources': an unchanged tree is not parsed
    again, and a change in a module is still seen (one the kernels import, the tolerances: see
    test_a_changed_tolerance_reaches_the_compiled_kernels)."""
    import fracture.refine as refine_package
    from fracture.refine import clear_stale_numba_cache

    pkg = tmp_path / "kernels"
    (pkg / "__pycache__").mkdir(parents=True)
    (pkg / "k.py").write_text("import numba\nfrom fracture.tolerances import tol\n")
    clear_stale_numba_cache([pkg])
    compiled = pkg / "__pycache__" / "k.f-1.py311.1.nbc"
    compiled.write_bytes(b"machine code")
    parsed = []
    real = refine_package.kernel_sources
    monkeypatch.setattr(refine_package, "kernel_sources", lambda *a: parsed.append(a) or real(*a))
    assert not clear_stale_numba_cache([pkg]) and not parsed and compiled.exists()
    (pkg / "k.py").write_text("import numba\nfrom fracture.tolerances import tol\nx = 2\n")
    assert clear_stale_numba_cache([pkg]) and len(parsed) == 1 and not compiled.exists()
    assert not clear_stale_numba_cache([pkg]) and len(parsed) == 1


@pytest.mark.slow
def test_a_changed_tolerance_reaches_the_compiled_kernels(tmp_path):
    """The flips' kernel reads the Delaunay tolerance as a module constant, frozen into its cached machine
    code; the tolerance lives in another file (fracture/tolerances.py). In a copy of the package: a quad
    whose diagonal is not Delaunay is flipped; with the tolerance raised past any angle sum it is not, on
    the next run, from the same cache directory."""
    import shutil

    root = Path(__file__).resolve().parents[1]
    for package in ("fracture", "fields"):
        shutil.copytree(root / package, tmp_path / package, ignore=shutil.ignore_patterns("__pycache__"))
    script = (
        "import numpy as np\n"
        "from fracture.process import prepare_process\n"
        "prepare_process(allocator=False)\n"
        "from fracture.refine.flips import flip_edges\n"
        "V = np.array([[0.0, 0, 0], [1, 0, 0], [0.5, 0.1, 0], [0.5, -0.1, 0]])\n"
        "F = np.array([[0, 1, 2], [1, 0, 3]], np.int64)\n"
        "print(flip_edges(V, F, np.array([[0, 1], [0, 1]], np.int64)))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "NUMBA_DISABLE_JIT")}
    env["PYTHONPATH"] = str(tmp_path)

    def flips() -> int:
        done = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True)
        assert done.returncode == 0, done.stderr[-2000:]
        return int(done.stdout.split()[-1])

    assert flips() == 1 and flips() == 1  # compiled, then from the cache
    assert list((tmp_path / "fracture" / "refine" / "__pycache__").glob("flips.*.nbc"))
    tolerances = tmp_path / "fracture" / "tolerances.py"
    text = tolerances.read_text()
    assert "tol.delaunay = 1e-12" in text
    tolerances.write_text(text.replace("tol.delaunay = 1e-12", "tol.delaunay = 1e9"))
    assert flips() == 0


def test_the_command_line_runs_the_kernels_on_gnu_openmp_with_a_thread_per_core(tmp_path, small_config):
    """``fracref run`` chooses the threading layer (GNU OpenMP: a kernel starts in microseconds, where the
    work queue takes a tenth of a millisecond) and a thread per core it may run on, pinned to fewer too;
    a layer named in the environment is kept."""
    from fracture.process import THREADING_LAYER, cores

    env = {k: v for k, v in os.environ.items() if k != "NUMBA_THREADING_LAYER"}
    one = sorted(os.sched_getaffinity(0))[:1]

    def run(name, pinned=False, **extra):
        cmd = [sys.executable, "-m", "fracref", "run", str(small_config), "--out", str(tmp_path / name), "--quiet",
               "--until", "refine", "--set", "refine.iterations=2"]
        if pinned:
            cmd = ["taskset", "-c", ",".join(map(str, one)), *cmd]
        out = subprocess.run(cmd, capture_output=True, text=True, env={**env, **extra})
        assert out.returncode == 0, out.stderr[-2000:]
        import json

        return json.loads((tmp_path / name / "manifest.json").read_text())["threads"]

    env.pop("OMP_WAIT_POLICY", None)
    assert THREADING_LAYER == "omp"
    assert run("all") == {"threads": cores(), "layer": "omp", "wait": "passive"}
    assert run("one", pinned=True) == {"threads": 1, "layer": "omp", "wait": "passive"}
    assert run("kept", NUMBA_THREADING_LAYER="workqueue")["layer"] == "workqueue"
    assert run("spinning", OMP_WAIT_POLICY="ACTIVE")["wait"] == "active"


def test_gnu_openmp_reads_the_wait_policy_the_process_set_up_chose():
    """The policy reaches GNU OpenMP only if it is in the environment before the library is loaded:
    prepare_process sets it first, and the library's own report of its settings shows it."""
    from fracture.process import WAIT_POLICY

    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_THREADING_LAYER", "OMP_WAIT_POLICY")}
    code = ("from fracture.process import prepare_process; prepare_process(allocator=False)\n"
            "import numba; print(numba.threading_layer())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**env, "OMP_DISPLAY_ENV": "TRUE"})
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["omp"]
    assert f"OMP_WAIT_POLICY = '{WAIT_POLICY.upper()}'" in out.stderr


def test_a_stopped_compile_stops_its_second_process_and_leaves_no_run_behind(tmp_path):
    """``fracref compile`` on two processes, stopped by SIGTERM once both have made their run directories: one
    line, the terminated status, and neither directory nor the second process left. It compiles into a numba
    cache of its own, so that it is still compiling when the signal comes."""
    import signal
    import time

    scratch = tmp_path / "tmp"
    scratch.mkdir()
    fracref = Path(sys.executable).with_name("fracref")
    env = {**os.environ, "TMPDIR": str(scratch), "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    proc = subprocess.Popen([str(fracref), "compile", "--processes", "2"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while len(list(scratch.glob("fracref-compile-*"))) < 2 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(list(scratch.glob("fracref-compile-*"))) == 2 and proc.poll() is None, "both did not begin"
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 128 + signal.SIGTERM, err
        assert "terminated" in err and "Traceback" not in err, err
        assert not list(scratch.iterdir())
        deadline = time.monotonic() + 20  # multiprocessing's resource tracker ends once the program has
        while (alive := subprocess.run(["pgrep", "-a", "-s", str(proc.pid)], capture_output=True, text=True).stdout
               ) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not alive, f"processes of the compile left: {alive}"
    finally:  # whatever is left of the session, the second process too
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)

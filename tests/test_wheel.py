"""The package installed from its wheel works away from the checkout: its kernels compile into the fresh install's
cache, and a config outside the repository names a built-in scene and a strength preset by name, runs to the end
and is exported.

The wheel is built from the checkout and installed, without its dependencies, into a fresh virtual
environment in a temporary directory; the dependencies (numpy, Open3D, usd-core, ...: gigabytes that
``make install`` has put into the project's environment) are read from that environment by a path
line, which adds its folder to the search path without running what its ``.pth`` files run (the
checkout's editable install among them). The runs start in the temporary directory, so nothing of the
checkout is on the path: what is not in the wheel (the presets, the meshes they name) is missing.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import textwrap
import venv
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """A fresh environment with the project's wheel; returns its ``bin`` folder."""
    tmp = tmp_path_factory.mktemp("wheel")
    dist = tmp / "dist"
    # built from a copy of the sources (setuptools builds in the source tree), links kept as links
    source = tmp / "source"
    shutil.copytree(REPO, source, symlinks=True, ignore=shutil.ignore_patterns(
        ".git", ".venv*", "runs", "build", "*.egg-info", "__pycache__", ".pytest_cache", "examples", "tests"))
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet",
                            "--wheel-dir", str(dist), str(source)], capture_output=True, text=True)
    assert build.returncode == 0, build.stderr[-3000:]
    wheel = next(dist.glob("fracref-*.whl"))
    env = tmp / "env"
    venv.EnvBuilder(with_pip=False).create(env)
    site = next((env / "lib").glob("python*/site-packages"))
    (site / "project_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    install = subprocess.run([sys.executable, "-m", "pip", "--python", str(env / "bin" / "python"), "install",
                              "--no-deps", "--quiet", str(wheel)], capture_output=True, text=True)
    assert install.returncode == 0, install.stderr[-3000:]
    return env / "bin"


# the installed package's own numba cache (beside its modules), compiled for real
_ENV = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "NUMBA_DISABLE_JIT")}


def _run(bin_dir: Path, cwd: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(bin_dir / "fracref"), *args], capture_output=True, text=True, cwd=cwd, timeout=900,
                          env=_ENV)


@pytest.mark.slow
def test_the_wheel_runs_a_scene_with_a_preset_by_name_and_exports_it(installed, tmp_path):
    where = subprocess.run([str(installed / "python"), "-c", "import fracture, fields; print(fracture.__file__); "
                            "print(fields.__file__)"], capture_output=True, text=True, cwd=tmp_path)
    assert where.returncode == 0, where.stderr
    assert all(str(installed.parent) in line for line in where.stdout.split()), where.stdout  # not the checkout's

    # `fracref compile` (which `make install` runs) fills the kernel cache of the fresh install, so that its
    # first run does not wait for the compilation
    cached = [str(installed / "python"), "-c", "from fracture.refine import kernels_cached; print(kernels_cached())"]
    assert subprocess.run(cached, capture_output=True, text=True, cwd=tmp_path, env=_ENV).stdout.strip() == "False"
    # in a temporary folder of its own: another program's leftovers in the machine's /tmp are not its own; in one
    # process, as this test's worker shares the cores with another (make install compiles in two, and
    # test_process stops the two)
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    compiled = subprocess.run([str(installed / "fracref"), "compile", "--processes", "1"], capture_output=True,
                              text=True, cwd=tmp_path, timeout=900, env={**_ENV, "TMPDIR": str(scratch)})
    assert compiled.returncode == 0 and "kernels compiled and cached in" in compiled.stdout, compiled.stderr[-2000:]
    assert subprocess.run(cached, capture_output=True, text=True, cwd=tmp_path, env=_ENV).stdout.strip() == "True"
    # every one of the refinement's: those a small grid does not reach too (the two-level search's, the flips'
    # collision test), which the built-in example calls
    uncached = [str(installed / "python"), "-c", "import pathlib, fracture.refine as r; "
                "print(r.uncached_kernels(pathlib.Path(r.__file__).parent))"]
    assert subprocess.run(uncached, capture_output=True, text=True, cwd=tmp_path, env=_ENV).stdout.strip() == "[]"
    assert not list(scratch.iterdir())  # its run directory is gone

    listed = _run(installed, tmp_path, "presets")
    assert listed.returncode == 0 and "strength/marble" in listed.stdout and "bunny" in listed.stdout, listed.stderr

    (tmp_path / "mine.yaml").write_text(textwrap.dedent("""\
        defaults: [strength/clay]
        input: {kind: scene, scene: clay, frames: 6}
        grid: {resolution: 24}
        refine: {max_triangles: 3000, iterations: 8}
        animate: {check_samples: 1000}
        """))
    run = _run(installed, tmp_path, "run", "mine.yaml", "--out", "out", "--quiet")
    assert run.returncode == 0, (run.stdout[-2000:], run.stderr[-3000:])
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["counts"]["pieces"] >= 2 and "animate" in manifest["stages"]
    export = _run(installed, tmp_path, "export", "out", "--out", "pieces.usda")
    assert export.returncode == 0 and (tmp_path / "pieces.usda").is_file(), export.stderr

    # a preset of the experiments too, and an unknown name that lists what exists
    (tmp_path / "wall.yaml").write_text("defaults: [example]\n")
    shown = _run(installed, tmp_path, "config", "wall.yaml")
    assert shown.returncode == 0 and "meshes/wall.obj" in shown.stdout, shown.stderr
    (tmp_path / "bad.yaml").write_text("defaults: [strength/granite]\n")
    bad = _run(installed, tmp_path, "config", "bad.yaml")
    assert bad.returncode != 0 and "strength/granite" in bad.stderr and "strength/bricks" in bad.stderr
    assert "Traceback" not in bad.stderr

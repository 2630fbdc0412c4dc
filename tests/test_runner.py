import hashlib
import json
import subprocess
import sys

import numpy as np
import pytest
import yaml

from conftest import CONFIGS, REPO
from fields.grid import Grid
from fracture.pipeline import runner
import errno
import os
import shutil
from pathlib import Path

from fracture.io.atomic import OutputError, RunDirectoryExists, atomic_write_text, staged_directory
from fracture.pipeline.config import load_config
from fracture.pipeline.stages import STAGES, Stage
from fracture.errors import ConfigError, InputError, StageError


def fracref(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "fracref", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=300)


def sha256(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_cli_run_writes_a_complete_run_directory(tmp_path, small_config):
    out = tmp_path / "run"
    res = fracref("run", small_config, "--out", out, "--quiet", "--set", "psi.stress_weight=0.5")
    assert res.returncode == 0, res.stderr
    assert f"run complete: {out}" in res.stdout
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["seed"] == 7 and manifest["name"] == "small"
    assert manifest["stages"]["fields"]["seconds"] > 0
    assert set(manifest["packages"]) >= {"numpy", "scipy", "open3d", "pymeshlab", "libigl", "noise"}
    assert manifest["counts"]["grid_nodes"] == int(np.prod(manifest["stats"]["fields"]["grid_shape"]))
    for rel, entry in manifest["files"].items():
        assert sha256(out / rel) == entry["sha256"], rel
    assert {"config.yaml", "fields/psi.npy", "fields/zeta.npy", "fields/xi.npy", "fields/pyramid.npy",
            "fields/grid.json", "fields/preview.png"} <= set(manifest["files"])
    # The saved config reproduces the run, including the override.
    saved = yaml.safe_load((out / "config.yaml").read_text())
    assert saved["psi"]["stress_weight"] == 0.5
    grid = Grid.from_dict(json.loads((out / "fields/grid.json").read_text()))
    psi = np.load(out / "fields/psi.npy")
    assert psi.shape == grid.shape and np.isfinite(psi).all()
    assert np.load(out / "fields/pyramid.npy").shape == (3,) + grid.shape
    # Nothing else is left next to the run (no staging directories).
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


def test_same_config_and_seed_give_byte_identical_outputs(tmp_path, small_config):
    runs = []
    for i, seed in enumerate((7, 7, 8)):
        cfg = load_config(small_config, [f"seed={seed}"])
        runs.append(runner.run(cfg, tmp_path / f"r{i}", progress=False))
    files = json.loads((runs[0] / "manifest.json").read_text())["files"]
    numeric = [rel for rel in files if rel.endswith((".npy", ".png", ".json", ".yaml"))]
    for rel in numeric:
        assert sha256(runs[0] / rel) == sha256(runs[1] / rel), rel
    assert sha256(runs[0] / "fields/zeta.npy") != sha256(runs[2] / "fields/zeta.npy")


def test_existing_run_is_kept_without_force_and_replaced_with_it(tmp_path, small_config):
    out = tmp_path / "run"
    assert fracref("run", small_config, "--out", out, "--quiet").returncode == 0
    before = sha256(out / "manifest.json")
    res = fracref("run", small_config, "--out", out, "--quiet", "--set", "seed=1")
    assert res.returncode == 2 and "run directory exists" in res.stderr and "--force" in res.stderr
    assert sha256(out / "manifest.json") == before
    res = fracref("run", small_config, "--out", out, "--quiet", "--set", "seed=1", "--force")
    assert res.returncode == 0, res.stderr
    assert json.loads((out / "manifest.json").read_text())["seed"] == 1
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_failed_run_writes_nothing_and_keeps_the_previous_run(tmp_path, small_config):
    out = tmp_path / "run"
    runner.run(load_config(small_config), out, progress=False)
    before = {p.name: sha256(p) for p in out.rglob("*") if p.is_file()}

    def explode(ctx):
        ctx.save_array("fields/psi.npy", np.zeros(3))  # a partial write ...
        raise KeyboardInterrupt  # ... then an interruption

    stages = tuple(Stage(s.name, explode) if s.name == "fields" else s for s in STAGES)
    with pytest.raises(KeyboardInterrupt):
        runner.run(load_config(small_config), out, force=True, progress=False, stages=stages)
    after = {p.name: sha256(p) for p in out.rglob("*") if p.is_file()}
    assert after == before
    assert [p.name for p in tmp_path.iterdir() if p.name != "run" and p.name.startswith(".")] == []


def test_bad_input_mesh_fails_before_anything_is_written(tmp_path, small_config):
    (tmp_path / "open.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    out = tmp_path / "run"
    res = fracref("run", small_config, "--out", out, "--set", f"input.exterior={tmp_path / 'open.obj'}")
    assert res.returncode == 2
    assert "input.exterior" in res.stderr and "open.obj" in res.stderr and "closed surface" in res.stderr
    assert "Traceback" not in res.stderr
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_config_errors_and_bad_stage_are_reported_without_running(tmp_path, small_config):
    out = tmp_path / "run"
    res = fracref("run", small_config, "--out", out, "--set", "pyramid.levels=0")
    assert res.returncode == 2 and "pyramid.levels: got 0 (int), expected an integer in [1, 8]" in res.stderr
    res = fracref("run", small_config, "--out", out, "--until", "mesh")
    assert res.returncode == 2 and "unknown stage" in res.stderr
    assert not out.exists()
    with pytest.raises(StageError, match="unknown stage"):
        runner.stages_until("bogus")


def test_missing_inputs_are_explained(tmp_path):
    cfg_path = tmp_path / "bare.yaml"
    cfg_path.write_text("seed: 1\n")
    with pytest.raises(InputError, match="set input.exterior and input.fracture"):
        runner.run(load_config(cfg_path), tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()


def test_cli_config_and_stages(small_config):
    res = fracref("config", small_config, "--set", "seed=3")
    assert res.returncode == 0 and yaml.safe_load(res.stdout)["seed"] == 3
    res = fracref("stages")
    assert res.returncode == 0 and "fields" in res.stdout.split()


def test_atomic_write_replaces_whole_files(tmp_path):
    target = tmp_path / "a" / "b.txt"
    atomic_write_text(target, "one")
    atomic_write_text(target, "two")
    assert target.read_text() == "two"
    assert [p.name for p in target.parent.iterdir()] == ["b.txt"]


def test_existing_non_directory_is_refused(tmp_path, small_config):
    (tmp_path / "file").write_text("x")
    with pytest.raises(RunDirectoryExists):
        runner.run(load_config(small_config), tmp_path / "file", force=True, progress=False)


def test_a_run_says_its_notes_quiet_or_not(tmp_path, small_config):
    """A material with no weak places is no error, but the user must hear of it where the run ends."""
    for quiet in ((), ("--quiet",)):
        out = tmp_path / f"run{len(quiet)}"
        res = fracref("run", small_config, "--out", out, "--until", "fields", *quiet,
                      "--set", "strength.layers[0].weight=0")
        assert res.returncode == 0, res.stderr
        assert "notes:\n  - fields: the strength layers give zeta = 0 everywhere" in res.stdout, res.stdout
        assert res.stdout.rstrip().endswith(f"run complete: {out}  (manifest: {out / 'manifest.json'})")


def test_force_replaces_only_an_earlier_run(tmp_path, small_config):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    res = fracref("run", small_config, "--out", mine, "--force", "--until", "coarse")
    assert res.returncode == 2 and "is not a run directory (it has no manifest.json)" in res.stderr
    assert (mine / "notes.txt").read_text() == "keep" and len(list(mine.iterdir())) == 1
    run = tmp_path / "run"
    runner.run(load_config(small_config), run, until="coarse", progress=False)
    first = (run / "manifest.json").read_bytes()
    runner.run(load_config(small_config, ["seed=5"]), run, until="coarse", force=True, progress=False)
    assert (run / "manifest.json").read_bytes() != first


def test_force_over_a_link_to_a_run_replaces_the_link_and_leaves_the_run_it_named(tmp_path):
    """``--out`` a link to an earlier run, with --force: the new run takes the link's place, nothing is left
    beside it, and the run the link named is as it was."""
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    (earlier / "manifest.json").write_text("{}")
    link = tmp_path / "link"
    link.symlink_to(earlier)
    with staged_directory(link, force=True) as staging:
        (staging / "manifest.json").write_text('{"new": 1}')
    assert not link.is_symlink() and json.loads((link / "manifest.json").read_text()) == {"new": 1}
    assert (earlier / "manifest.json").read_text() == "{}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["earlier", "link"]


def test_an_output_path_through_a_file_is_one_line(tmp_path, small_config):
    (tmp_path / "afile").write_text("x")
    res = fracref("run", small_config, "--out", tmp_path / "afile" / "sub", "--until", "coarse")
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert f"{tmp_path / 'afile'} is a file, not a directory" in res.stderr


def test_staging_of_killed_runs_is_removed_by_the_next_run(tmp_path, small_config):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = tmp_path / f".run.partial-{int(dead.stdout)}-abcd"
    live = tmp_path / f".run.partial-{os.getpid()}-efgh"  # a run still going: left alone
    for d in (stale, live):
        d.mkdir()
        (d / "fields").mkdir()
    runner.run(load_config(small_config), tmp_path / "run", until="coarse", progress=False)
    assert not stale.exists() and live.exists()


def test_a_run_killed_between_its_two_moves_gets_its_earlier_run_back(tmp_path):
    """A run replacing another moves that one to ``.NAME.old-PID-XXXX``, then itself into place, then deletes
    the old one: killed after the first move, no run is left at NAME, and the next run into the same place
    moves the earlier one back first; killed after the second, the old one's remains are deleted."""
    from fracture.io.atomic import remove_stale_staging

    dead = int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                              text=True).stdout)
    out = tmp_path / "run"
    old = tmp_path / f".run.old-{dead}-abcd"
    old.mkdir()
    (old / "manifest.json").write_text("{}")
    live = tmp_path / f".run.old-{os.getpid()}-efgh"  # a run still going: left alone
    live.mkdir()
    with pytest.raises(RunDirectoryExists):  # a new run there without --force: the earlier one is back first
        with staged_directory(out):
            pass
    assert (out / "manifest.json").read_text() == "{}" and not old.exists() and live.exists()
    old.mkdir()  # the new run in place, the old one's remains beside it
    assert remove_stale_staging(out) == [old] and out.is_dir() and not old.exists() and live.exists()


def test_a_stop_while_the_replaced_run_is_deleted_says_the_new_one_is_in_place(tmp_path, monkeypatch):
    import fracture.io.atomic as atomic

    out = tmp_path / "run"
    out.mkdir()
    (out / "manifest.json").write_text("old")
    real = shutil.rmtree

    def stopped(path, *a, **k):  # Ctrl-C while the replaced run is deleted
        if ".run.old-" in str(path):
            raise KeyboardInterrupt
        return real(path, *a, **k)

    monkeypatch.setattr(atomic.shutil, "rmtree", stopped)
    with pytest.raises(KeyboardInterrupt) as stop:
        with staged_directory(out, force=True) as staging:
            (staging / "manifest.json").write_text("new")
    assert stop.value.run_in_place == out.absolute() and (out / "manifest.json").read_text() == "new"
    monkeypatch.undo()
    # what is left of the old run, named after this process (still running: no later run takes it yet)
    assert [p.name.split("-")[:2] for p in tmp_path.glob(".run.*")] == [[".run.old", str(os.getpid())]]


def test_the_command_line_says_a_stop_after_the_run_was_written(tmp_path, small_config, capsys, monkeypatch):
    """Ctrl-C while ``fracref run --force`` deletes the run it replaced: the new run is whole and in place,
    and the command says so (not "nothing was written")."""
    import fracture.io.atomic as atomic
    from fracref.cli import main

    args = ["run", str(small_config), "--out", str(tmp_path / "run"), "--until", "coarse", "--quiet", "--force",
            "--no-cache"]
    assert main(args) == 0
    real = shutil.rmtree

    def stopped(path, *a, **k):
        if ".run.old-" in str(path):
            raise KeyboardInterrupt
        return real(path, *a, **k)

    monkeypatch.setattr(atomic.shutil, "rmtree", stopped)
    capsys.readouterr()
    assert main(args) == 130
    assert capsys.readouterr().err == (f"fracref: interrupted after the run was written whole to {tmp_path / 'run'}; "
                                       "what is left of the run it replaced goes with the next run there\n")
    assert (tmp_path / "run" / "manifest.json").is_file()


def test_a_cache_folder_that_is_a_file_is_refused_by_name(tmp_path, small_config):
    blocker = tmp_path / "afile.txt"
    blocker.write_text("x")
    for where in (blocker, blocker / "cache"):
        out = subprocess.run([sys.executable, "-m", "fracref", "run", str(small_config), "--out", str(tmp_path / "r"),
                              "--cache-dir", str(where), "--until", "coarse"], cwd=REPO, capture_output=True, text=True)
        assert out.returncode == 2 and "Traceback" not in out.stderr
        assert f"--cache-dir {where}: {blocker} is a file, not a folder" in out.stderr
        assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("name, value, words", [
    ("FRACREF_CACHE_DIR", "{blocker}", "FRACREF_CACHE_DIR={blocker}: {blocker} is a file, not a folder"),
    ("FRACREF_CACHE_MAX_GB", "abc", "FRACREF_CACHE_MAX_GB='abc': expected the stage cache's size in gigabytes"),
    ("FRACREF_CACHE_MAX_GB", "nan", "FRACREF_CACHE_MAX_GB='nan': expected the stage cache's size in gigabytes"),
    ("NUMBA_NUM_THREADS", "0", "NUMBA_NUM_THREADS='0': expected a whole number of threads from 1"),
    ("NUMBA_THREADING_LAYER", "bogus", "NUMBA_THREADING_LAYER='bogus': expected one of default, safe"),
])
def test_a_setting_of_the_environment_that_cannot_be_used_is_refused_by_name(tmp_path, small_config, name, value,
                                                                              words):
    """The cache a user named in the environment, as --cache-dir is; numba's settings, which numba refuses with a
    traceback when it is imported (so the command line asks before it imports numba)."""
    blocker = tmp_path / "afile.txt"
    blocker.write_text("x")
    env = {**os.environ, name: value.format(blocker=blocker)}
    out = subprocess.run([sys.executable, "-m", "fracref", "run", str(small_config), "--out", str(tmp_path / "r"),
                          "--until", "coarse"], cwd=REPO, capture_output=True, text=True, env=env)
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    assert out.stderr.startswith(f"fracref: error: {words.format(blocker=blocker)}"), out.stderr
    assert len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert not (tmp_path / "r").exists()


def test_a_full_disk_leaves_nothing_and_says_so(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(OutputError, match=r"cannot write the run \(.*No space left on device.*\); nothing was written"):
        with staged_directory(out) as staging:
            (staging / "big.npy").write_bytes(b"partial")
            raise OSError(errno.ENOSPC, "No space left on device", str(staging / "big.npy"))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("signame, said", [("SIGTERM", "terminated"), ("SIGHUP", "stopped (its terminal closed)")])
def test_a_killed_cli_run_removes_its_staging(tmp_path, small_config, signame, said):
    import signal
    import time

    signum = getattr(signal, signame)
    proc = subprocess.Popen([sys.executable, "-m", "fracref", "run", str(small_config), "--out", str(tmp_path / "run"),
                             "--quiet"], cwd=REPO, stderr=subprocess.PIPE, text=True)
    while not list(tmp_path.glob(".run.partial-*")) and proc.poll() is None:
        time.sleep(0.05)
    proc.send_signal(signum)
    proc.wait(timeout=120)
    err = proc.stderr.read()
    assert proc.returncode != 0 or (tmp_path / "run").is_dir()  # killed, or it had already finished
    if proc.returncode != 0:
        assert proc.returncode == 128 + signum and err.endswith(f"fracref: {said}; nothing was written\n"), err
    assert not list(tmp_path.glob(".run.*"))
    assert "Traceback" not in err


def test_a_grid_beyond_the_memory_limit_is_refused_before_it_is_allocated(tmp_path, small_config):
    cfg = load_config(small_config, ["grid.resolution=[1024, 1024, 1024]"])
    with pytest.raises(ConfigError, match=r"1024x1024x1024 grid .* need about [0-9.]+ GB, more than grid\.max_memory_gb"):
        runner.run(cfg, tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists() and not list(tmp_path.glob(".run.*"))


@pytest.mark.slow
@pytest.mark.parametrize("path", sorted(CONFIGS.glob("*.yaml")), ids=lambda p: p.name)
def test_every_experiment_runs_shrunk(tmp_path, path):
    cfg = load_config(path, ["grid.resolution=16", "pyramid.levels=2", "refine.max_triangles=5000"])
    out = runner.run(cfg, tmp_path / "run", progress=False)
    manifest = json.loads((out / "manifest.json").read_text())
    assert list(manifest["stages"]) == runner.available_stages()
    psi = np.load(out / "fields/psi.npy")
    assert np.isfinite(psi).all() and psi.max() > psi.min()


def test_a_cut_with_mixed_face_orientations_makes_the_same_pieces(tmp_path):
    """Half the cut's faces reversed: the import turns them back, so the pieces are the true halves."""
    lines = (REPO / "configs/meshes/cube_cut.obj").read_text().splitlines()
    faces = [i for i, line in enumerate(lines) if line.startswith("f ")]
    for i in faces[len(faces) // 2:]:
        head, *corners = lines[i].split()
        lines[i] = " ".join([head] + corners[::-1])
    (tmp_path / "mixed.obj").write_text("\n".join(lines) + "\n")
    volumes = {}
    for name in ("cube_cut.obj", "mixed.obj"):
        cut = REPO / "configs/meshes/cube_cut.obj" if name == "cube_cut.obj" else tmp_path / name
        cfg = load_config(REPO / "configs/example.yaml",
                          ["input.kind=meshes", f"input.exterior={REPO / 'configs/meshes/cube.obj'}",
                           f"input.fracture={cut}", "grid.resolution=24", "refine.max_triangles=3000"])
        out = runner.run(cfg, tmp_path / f"run_{name}", progress=False)
        manifest = json.loads((out / "manifest.json").read_text())
        volumes[name] = sorted(p["volume"] for p in manifest["stats"]["animate"]["pieces"])
        assert all(p["closed_oriented"] for p in manifest["stats"]["animate"]["pieces"])
    assert any("25 faces turned" in n for n in manifest["notes"])
    assert volumes["mixed.obj"] == pytest.approx(volumes["cube_cut.obj"], abs=1e-6)
    assert volumes["mixed.obj"][0] > 0.4


def test_a_run_shows_full_bars_and_ends_with_its_seconds_per_stage(tmp_path, small_config):
    out = tmp_path / "run"
    res = fracref("run", small_config, "--out", out)
    assert res.returncode == 0, res.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    lines = res.stderr.replace("\r", "\n").splitlines()
    for name in manifest["stages"]:
        bars = [ln for ln in lines if ln.startswith(f"{name}")]
        if bars:  # the stage has a bar: its last state is full
            assert "100%" in bars[-1], (name, bars[-1])
    table = res.stdout.split("time per stage:")[1]
    for name, info in manifest["stages"].items():
        assert f"{name}" in table and f"{info['seconds']:.1f} s" in table
    assert "total" in table


def test_a_cold_kernel_cache_is_told_apart_from_a_warm_one(tmp_path):
    from fracture.refine import kernels_cached, uncached_kernels

    pkg = tmp_path / "kernels"
    (pkg / "__pycache__").mkdir(parents=True)
    (pkg / "a.py").write_text("import numba\n\n@numba.njit(cache=True)\ndef one(x):\n    return x\n\n"
                              "@numba.njit(cache=True, inline='always')\ndef helper(x):\n    return x\n\n"
                              "@numba.njit(cache=True)\ndef two(x):\n    return x\n")
    assert not kernels_cached(pkg)  # nothing compiled yet: a first run compiles
    (pkg / "__pycache__" / "a.one-4.py311.nbi").write_bytes(b"")
    assert kernels_cached(pkg)  # most of it (a run compiles only what it calls)
    assert uncached_kernels(pkg) == ["kernels.a.two"]
    (pkg / "__pycache__" / "a.one-4.py311.nbi").unlink()
    (pkg / "__pycache__" / "b.one-4.py311.nbi").write_bytes(b"")  # another module's
    assert not kernels_cached(pkg)


def test_a_file_that_fails_to_be_written_fails_the_run_and_leaves_nothing(tmp_path, small_config, monkeypatch):
    """Files are written beside the stages; one whose write fails (a full disk, say) fails the run, which
    then leaves no directory, and a run after it is whole."""
    from fracture.pipeline import context

    def full(path, array):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(context, "_write_npy", full)
    with pytest.raises(OutputError, match="No space left"):
        runner.run(load_config(small_config), tmp_path / "run", until="fields", progress=False)
    assert not (tmp_path / "run").exists() and [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    monkeypatch.undo()
    out = runner.run(load_config(small_config), tmp_path / "run", until="fields", progress=False)
    manifest = json.loads((out / "manifest.json").read_text())
    for rel, info in manifest["files"].items():
        assert (out / rel).stat().st_size == info["bytes"] and sha256(out / rel) == info["sha256"]


@pytest.mark.parametrize("signum", ["SIGINT", "SIGTERM"])
def test_a_stop_inside_a_compiler_callback_is_taken_after_it(monkeypatch, signum):
    """The command line's Ctrl-C and SIGTERM handler: inside a callback from llvmlite's C code (where an
    exception would be printed and dropped, and the run go on) it sends the signal again a moment later;
    elsewhere it stops the command as Ctrl-C does, with the signal's exit status."""
    import signal
    import time

    from fracref import cli

    signum = getattr(signal, signum)
    sent = []
    monkeypatch.setattr(cli.os, "kill", lambda pid, sig: sent.append((pid, sig)))
    namespace = {"sys": sys}
    exec(compile("def callback():\n    return sys._getframe()\n",
                 "/venv/site-packages/llvmlite/binding/executionengine.py", "exec"), namespace)
    cli._stop(signum, namespace["callback"]())  # returns: no exception inside the callback
    for _ in range(100):
        if sent:
            break
        time.sleep(0.02)
    assert sent == [(os.getpid(), signum)]
    with pytest.raises(KeyboardInterrupt) as stop:
        cli._stop(signum, sys._getframe())
    assert stop.value.code == 128 + signum


def test_an_error_while_a_stop_unwinds_is_said_as_the_stop(monkeypatch, capsys):
    """A kernel half compiled when Ctrl-C came breaks what runs next ("no compiled object yet"): the command
    says it was interrupted, in one line, not what the interruption broke."""
    import signal

    from fracref import cli

    def broken(argv):
        cli._stopped_by.append(signal.SIGINT)
        raise RuntimeError("no compiled object yet for <Library '_pairs'>")

    monkeypatch.setattr(cli, "_main", broken)
    assert cli.main(["run", "x.yaml"]) == 130
    assert capsys.readouterr().err == "fracref: interrupted; nothing was written\n"


JOIN = ("the refined fracture surface cannot be joined to the object's surface near [0.5, 0.5, 0.5]: two of its "
        "cracks cross each other on the surface there")
CROSS = "piece 1 (b) crosses itself (3 triangle pairs meet) and the crossings could not be resolved"


@pytest.mark.parametrize("why", [JOIN, CROSS])
def test_a_searched_surface_that_makes_no_sound_pieces_is_refined_again_without_the_search(tmp_path, small_config,
                                                                                          monkeypatch, why):
    """The pieces cannot be made of the searched surface (as on some Blender exports: a rim of the searched
    cracks spans a part of the object thinner than its edge, or a piece crosses itself beyond repair): the
    run refines again with the flow alone, says so, and its files are those of a run with
    ``refine.search: none`` (the config file as given)."""
    import fracture.pipeline.stages.animate as animate
    from fracture.errors import JoinError, ResultError
    from fracture.pipeline.cache import StageCache

    imprint, verify, refused = animate.imprint_boundary, animate.verify_pieces, []

    def refuse_the_first(BV, BF, mesh, where="animate"):
        if why == JOIN and not refused:
            refused.append(len(mesh.F))
            raise JoinError(where, JOIN, "; advice")
        return imprint(BV, BF, mesh, where)

    def refuse_the_first_pieces(checks, names):
        if why == CROSS and not refused:
            refused.append(len(names))
            raise ResultError(f"animate: {CROSS}")
        return verify(checks, names)

    monkeypatch.setattr(animate, "imprint_boundary", refuse_the_first)
    monkeypatch.setattr(animate, "verify_pieces", refuse_the_first_pieces)
    searched = load_config(small_config, ["refine.search=graphcut", "refine.iterations=3"])
    for cache in (None, StageCache(tmp_path / "cache")):
        refused.clear()
        done = runner.run(searched, tmp_path / f"fallback_{cache is None}", progress=False, cache=cache)
        m = json.loads((done / "manifest.json").read_text())
        assert refused and m["stages"]["refine"]["without_search"] is True
        assert m["stats"]["refine"]["search"] is None  # the second refinement's record
        assert [n for n in m["notes"] if "search" in n] == [
            f"refine: the global search's surface was refused: {why}; refined again with the flow alone "
            "(refine.search: none), from the coarse surface"]
        assert yaml.safe_load((done / "config.yaml").read_text())["refine"]["search"] == "graphcut"
        plain = runner.run(load_config(small_config, ["refine.search=none", "refine.iterations=3"]),
                           tmp_path / f"plain_{cache is None}", progress=False)
        pm = json.loads((plain / "manifest.json").read_text())
        same = {k: v for k, v in pm["files"].items() if k != "config.yaml"}
        assert {k: v for k, v in m["files"].items() if k != "config.yaml"} == same
        assert m["counts"] == pm["counts"]
        if cache is None:
            continue
        # the cache keeps what each config refines to: the searched surface under the search's key, the flow
        # alone's under its own, with its files and counts; runs that reuse them are the same runs
        for k, config in enumerate([searched, load_config(small_config, ["refine.search=none", "refine.iterations=3"])]):
            refused.clear()
            again = runner.run(config, tmp_path / f"again_{k}", progress=False, cache=cache)
            am = json.loads((again / "manifest.json").read_text())
            assert am["stages"]["refine"]["cache"] == "reused"
            assert {k: v for k, v in am["files"].items() if k != "config.yaml"} == same
            assert am["counts"] == pm["counts"] and bool(refused) == (k == 0)


@pytest.mark.parametrize("refusals", [1, 2, 3])
def test_a_refined_surface_that_makes_no_sound_pieces_is_refined_again_with_other_draws(tmp_path, small_config,
                                                                                       monkeypatch, refusals):
    """The flow's own surface cannot be joined to B (as on a plank torus of the Blender sweeps: a rim doubling
    back where a sheet grazes a concave part of B): the run refines again with the next draws of the
    refinement's random choices (``refine.draw``), says so, and its files are those of a run with that draw;
    after the third refusal it stops with the last refusal and how many there were, and writes nothing."""
    import fracture.pipeline.stages.animate as animate
    from fracture.errors import JoinError

    imprint, refused = animate.imprint_boundary, []

    def refuse(BV, BF, mesh, where="animate"):
        if len(refused) < refusals:
            refused.append(len(mesh.F))
            raise JoinError(where, JOIN, "; advice")
        return imprint(BV, BF, mesh, where)

    monkeypatch.setattr(animate, "imprint_boundary", refuse)
    config = load_config(small_config, ["refine.iterations=3"])
    out = tmp_path / "redrawn"
    if refusals == 3:
        inputs = sorted(tmp_path.iterdir())
        with pytest.raises(JoinError) as error:
            runner.run(config, out, progress=False)
        assert str(error.value) == (f"animate: {JOIN}; advice (the surfaces of 3 refinements were refused, the last "
                                    "with refine.draw: 2)")
        assert sorted(tmp_path.iterdir()) == inputs  # nothing written beside them
        return
    done = runner.run(config, out, progress=False)
    m = json.loads((done / "manifest.json").read_text())
    assert len(refused) == refusals and len(set(refused)) >= 1
    assert m["stages"]["refine"]["tries"] == refusals + 1 and m["stages"]["refine"]["draw"] == refusals
    assert [n for n in m["notes"] if "refused" in n] == [
        f"refine: the refined surface was refused: {JOIN}; refined again with other random split positions "
        f"(refine.draw: {k + 1})" for k in range(refusals)]
    assert yaml.safe_load((done / "config.yaml").read_text())["refine"]["draw"] == 0
    monkeypatch.setattr(animate, "imprint_boundary", imprint)
    plain = runner.run(load_config(small_config, ["refine.iterations=3", f"refine.draw={refusals}"]),
                       tmp_path / "plain", progress=False)
    pm = json.loads((plain / "manifest.json").read_text())
    assert {k: v for k, v in m["files"].items() if k != "config.yaml"} == \
        {k: v for k, v in pm["files"].items() if k != "config.yaml"}
    assert m["counts"] == pm["counts"]
    # another draw is another refinement: other split positions
    first = runner.run(config, tmp_path / "first", progress=False)
    fm = json.loads((first / "manifest.json").read_text())
    refined = [f for f in fm["files"] if f.startswith("refined/")]
    assert refined and any(fm["files"][f] != pm["files"][f] for f in refined)


def test_a_run_that_has_nothing_to_do_says_so(tmp_path, small_config):
    """A uniform material, no flow step and no room to split: each said in a note, and the run still made."""
    plain = ("strength.layers=[{kind: radial, inner: 0.5, outer: 0.5}]")
    out = runner.run(load_config(small_config, [plain]), tmp_path / "plain", until="fields", progress=False)
    notes = json.loads((out / "manifest.json").read_text())["notes"]
    assert [n for n in notes if n.startswith("fields:")] == [
        "fields: the strength layers give zeta = 0 everywhere: the material has no weak places for the cracks to "
        "find; they follow the stress alone (the coarse surface, smoothed)"]
    notes = json.loads((runner.run(load_config(small_config), tmp_path / "marble", until="fields", progress=False)
                        / "manifest.json").read_text())["notes"]
    assert not [n for n in notes if n.startswith("fields:")]
    out = runner.run(load_config(small_config, ["refine.iterations=0", "refine.max_triangles=10",
                                                "refine.search=none"]),
                     tmp_path / "still", until="refine", progress=False)
    manifest = json.loads((out / "manifest.json").read_text())
    coarse = manifest["counts"]["coarse_fracture_triangles"]
    assert [n for n in manifest["notes"] if n.startswith("refine:")] == [
        "refine: refine.iterations is 0: no flow step ran; the coarse surface is the result",
        f"refine: refine.max_triangles (10) is not above the coarse surface's {coarse} triangles: nothing was split"]
    assert manifest["counts"]["refined_fracture_triangles"] == coarse


def test_a_refinement_that_ends_higher_than_it_began_says_so():
    from types import SimpleNamespace

    from fracture.pipeline.stages.refine import _outcome_notes
    from fracture.refine.params import RefineParams

    params = RefineParams()
    lower = SimpleNamespace(sampled=(0.66, 0.61), sampled_on_b=0.0, functional=[0.7, 0.6])
    assert _outcome_notes(params, lower, 100, searched=True) == []
    higher = SimpleNamespace(sampled=(0.658, 0.693), sampled_on_b=0.0, functional=[0.7, 0.6])
    assert _outcome_notes(params, higher, 100, searched=True) == [
        "refine: the refined surface scores higher on the functional than the coarse one (0.693 against 0.658, "
        "sampled alike); the flow lowered it as it measures it (psi at the vertices), not on dense samples"]
    rose = SimpleNamespace(sampled=(0.6, 0.7), sampled_on_b=0.0, functional=[0.6, 0.7])
    assert "as it measures it" not in _outcome_notes(params, rose, 100, searched=False)[0]
    # the coarse surface fitted onto B scored higher still: the flow lowered the functional from where it began
    fitted = SimpleNamespace(sampled=(0.7206, 0.7461), sampled_on_b=0.754, functional=[0.49, 0.75])
    assert _outcome_notes(params, fitted, 100, searched=False) == [
        "refine: the refined surface scores higher on the functional than the coarse one (0.7461 against 0.7206, "
        "sampled alike), whose rims cut across B's curves: fitted onto B the coarse surface scores 0.754, and the "
        "flow lowered it from there"]

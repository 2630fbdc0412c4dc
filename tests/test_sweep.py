"""Sweeps: every combination of values as its own run, tables and a contact sheet, resumable, on local
processes or Ray."""

import json

import pytest

from fracref.cli import main
from fracture.errors import ConfigError
from fracture.pipeline.sweep import parse_grid, points, run_sweep

GRID = {"psi.stress_weight": [0.2, 1.5], "seed": [7, 8]}


def statuses(out):
    return {name: p["status"] for name, p in json.loads((out / "sweep.json").read_text())["points"].items()}


def files(run_dir):
    return json.loads((run_dir / "manifest.json").read_text())["files"]


@pytest.fixture(scope="module")
def local_sweep(tmp_path_factory):
    """The 2 x 2 sweep of a small config with two local processes, through the command line."""
    from conftest import small_config_file

    base = tmp_path_factory.mktemp("sweep")
    config = small_config_file(base)
    out = base / "local"
    rc = main(["sweep", str(config), "--grid", "psi.stress_weight=0.2,1.5", "--grid", "seed=7,8", "--out", str(out),
               "--jobs", "2", "--quiet"])
    return config, out, rc


def test_a_sweep_runs_every_point_into_its_directory_with_tables_and_a_sheet(local_sweep):
    config, out, rc = local_sweep
    assert rc == 0
    names = [p.name for p in points(GRID)]
    assert names == ["psi.stress_weight=0.2,seed=7", "psi.stress_weight=0.2,seed=8",
                     "psi.stress_weight=1.5,seed=7", "psi.stress_weight=1.5,seed=8"]
    assert statuses(out) == {n: "ok" for n in names}
    for n in names:
        assert (out / n / "manifest.json").is_file()
    saved = json.loads((out / names[3] / "manifest.json").read_text())
    assert saved["seed"] == 8
    # the workers (spawned, set up as the command line is) ran the parallel kernels on the chosen layer
    # (the test suite's, from the environment), each on its share of the cores
    import os

    from fracture.process import THREADING_LAYER, cores

    for n in names:
        threads = json.loads((out / n / "manifest.json").read_text())["threads"]
        assert threads["layer"] == os.environ.get("NUMBA_THREADING_LAYER", THREADING_LAYER), threads
        assert threads["threads"] == max(1, cores() // 2), threads
    rows = (out / "table.csv").read_text().splitlines()
    assert len(rows) == 5 and rows[0].startswith("point,psi.stress_weight,seed,status,seconds")
    assert "weak_20" in rows[0] and "distance_mean" in rows[0] and "triangles" in rows[0]
    md = (out / "table.md").read_text().splitlines()
    assert len(md) == 6 and md[2].startswith(f"| {names[0]} | 0.2 | 7 | ok |")
    import imageio.v3 as iio

    sheet = iio.imread(out / "sheet.png")
    assert sheet.shape[0] > 500 and sheet.shape[1] > 700
    assert (sheet[..., :3] < 200).any(axis=2).mean() > 0.02  # surfaces, bars and captions drawn on white


def test_a_sweep_on_ray_gives_the_same_runs(local_sweep, tmp_path):
    ray = pytest.importorskip("ray")
    config, out, _ = local_sweep
    state = run_sweep(config, GRID, tmp_path / "ray", jobs=2, backend="ray", progress=False)
    assert not ray.is_initialized()  # the sweep's own local cluster is shut down again
    assert set(s["status"] for s in state["points"].values()) == {"ok"}
    for p in points(GRID):
        assert files(tmp_path / "ray" / p.name) == files(out / p.name), p.name  # the same bytes
    assert (tmp_path / "ray" / "table.csv").read_text().count("\n") == 5
    # a cluster address where nothing answers is refused at once, in one line
    for address in ("127.0.0.1:1", "ray://127.0.0.1:1", "nonsense", "auto"):
        with pytest.raises(ConfigError, match="--address"):
            run_sweep(config, GRID, tmp_path / "nowhere", backend="ray", address=address, progress=False)
    assert not (tmp_path / "nowhere").exists()


def test_a_resumed_sweep_runs_only_the_missing_points_and_a_failure_stops_no_other(local_sweep, tmp_path):
    import shutil

    config, out, _ = local_sweep
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    missing = points(GRID)[2].name
    shutil.rmtree(copy / missing)
    state = run_sweep(config, GRID, copy, progress=False)
    assert statuses(copy) == {p.name: ("ok" if p.name == missing else "done before") for p in points(GRID)}
    assert files(copy / missing) == files(out / missing)
    assert state["points"][missing]["status"] == "ok"
    # a point that fails at run time (its grid needs more memory than allowed: the fields stage refuses it)
    # is listed with its error, and the others run
    grid = {"grid.resolution": [1000, 20]}
    rc = main(["sweep", str(config), "--grid", "grid.resolution=1000,20", "--out", str(tmp_path / "f"), "--quiet",
               "--no-sheet"])
    assert rc == 2
    s = json.loads((tmp_path / "f" / "sweep.json").read_text())["points"]
    names = [p.name for p in points(grid)]
    assert s[names[0]]["status"] == "failed" and "grid.max_memory_gb" in s[names[0]]["error"], s
    assert s[names[1]]["status"] == "ok" and not (tmp_path / "f" / names[0]).exists()
    assert "failed" in (tmp_path / "f" / "table.md").read_text()


def test_a_resumed_sweep_runs_again_the_points_whose_config_or_stages_changed(local_sweep, tmp_path):
    """A complete point run with another config (the sweep asked again with another ``--set``) or other stages
    (``--until``) is not "done before": it runs again, and its earlier run is replaced once the new one is
    complete; the points that are what the sweep asks for are kept."""
    config, _, _ = local_sweep
    out = tmp_path / "s"
    grid = {"seed": [7, 8]}
    run_sweep(config, grid, out, until="coarse", progress=False)
    state = run_sweep(config, grid, out, overrides=["psi.stress_weight=3"], until="fields", progress=False)
    assert statuses(out) == {"seed=7": "ok", "seed=8": "ok"}
    assert state["points"]["seed=7"]["replaces"] == "an earlier run: its config changed"
    for name in ("seed=7", "seed=8"):
        assert "stress_weight: 3" in (out / name / "config.yaml").read_text()
        assert list(json.loads((out / name / "manifest.json").read_text())["stages"]) == ["coarse", "fields"]
    state = run_sweep(config, grid, out, overrides=["psi.stress_weight=3"], until="coarse", progress=False)
    assert state["points"]["seed=8"]["replaces"] == "an earlier run: it ran other stages (--until)"
    state = run_sweep(config, grid, out, overrides=["psi.stress_weight=3"], until="coarse", progress=False)
    assert statuses(out) == {"seed=7": "done before", "seed=8": "done before"}
    assert sorted(p.name for p in out.iterdir()) == ["seed=7", "seed=8", "sweep.json", "table.csv", "table.md"]


def test_a_value_given_twice_is_refused(local_sweep, tmp_path, capsys):
    config, _, _ = local_sweep
    for grid in ("psi.stress_weight=0.2,0.2", "seed=1,01", "psi.stress_weight=1,1.0", "grid.resolution=[8,8,8],[8,8,8.0]"):
        rc = main(["sweep", str(config), "--grid", grid, "--out", str(tmp_path / "twice"), "--quiet", "--no-sheet"])
        err = capsys.readouterr().err
        assert rc == 2 and "is given twice; expected distinct values" in err and "Traceback" not in err, err
        assert not (tmp_path / "twice").exists()
        if grid == "psi.stress_weight=1,1.0":
            assert "the value 1 (and 1.0, the same number) is given twice" in err, err


def test_sweep_grids_are_read_from_the_command_line_or_the_config_and_checked_first(local_sweep, tmp_path, capsys):
    config, _, _ = local_sweep
    assert parse_grid(["grid.resolution=[8,8,8],12", "seed=1"]) == {"grid.resolution": [[8, 8, 8], 12], "seed": [1]}
    for bad in (["seed="], ["seed=1", "seed=2"], ["=1,2"]):
        with pytest.raises(ConfigError, match="--grid"):
            parse_grid(bad)
    # a value that no run accepts stops the sweep before anything runs, naming the point
    rc = main(["sweep", str(config), "--grid", "pyramid.levels=3,99", "--out", str(tmp_path / "bad"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "pyramid.levels = 99" in err and "pyramid.levels" in err and "Traceback" not in err
    assert not (tmp_path / "bad").exists()
    # the config's own sweep.grid block
    text = config.read_text() + "sweep:\n  grid:\n    seed: [7]\n    psi.stress_weight: [0.5]\n"
    (config.parent / "with_grid.yaml").write_text(text)
    rc = main(["sweep", str(config.parent / "with_grid.yaml"), "--out", str(tmp_path / "g"), "--quiet", "--no-sheet"])
    assert rc == 0 and statuses(tmp_path / "g") == {"seed=7,psi.stress_weight=0.5": "ok"}


def test_values_that_would_share_a_point_folder_are_refused_before_anything_runs():
    with pytest.raises(ConfigError, match=r"the points input\.path = /data/a/b, seed = 0 and input\.path = /data/a_b, "
                                          r"seed = 0 would share the folder 'input\.path=__data_a_b_,seed=0'"):
        points({"input.path": ["/data/a/b", "/data/a_b"], "seed": [0]})


def test_a_failed_point_says_what_went_wrong_in_the_users_words(tmp_path):
    from fracture.pipeline.sweep import run_point

    (tmp_path / "c.yaml").write_text("input: {kind: meshes, exterior: nowhere.obj}\n")
    status = run_point(str(tmp_path / "c.yaml"), [], str(tmp_path / "run"), None, None, False)
    assert status["status"] == "failed" and status["error"].startswith(str(tmp_path / "c.yaml")), status
    assert "Error:" not in status["error"]



def test_a_terminated_sweep_leaves_no_half_written_point(tmp_path, small_config):
    """SIGTERM while two workers write their points: each worker unwinds as from Ctrl-C, so no point's staging
    stays in the sweep's folder."""
    import signal
    import subprocess
    import sys
    import time

    from conftest import REPO

    out = tmp_path / "sw"
    proc = subprocess.Popen([sys.executable, "-m", "fracref", "sweep", str(small_config), "--grid", "seed=1,2,3,4",
                             "--jobs", "2", "--out", str(out)], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    start = time.monotonic()
    while not list(out.glob(".*.partial-*")) and proc.poll() is None and time.monotonic() - start < 120:
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    if proc.returncode != 0:  # stopped (or it had already finished)
        assert proc.returncode == 128 + signal.SIGTERM and "the sweep's finished points are kept" in err, err
    assert "Traceback" not in err and not list(out.glob(".*")), list(out.glob(".*"))


def _deaf_worker(ready) -> None:
    """A worker that does not answer SIGTERM (as one may not while it waits on the pool)."""
    import signal
    import time

    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    ready.set()
    time.sleep(600)


def _worker_that_stops(ready) -> None:
    import time

    ready.set()
    time.sleep(600)


def test_stopped_workers_that_outlive_the_grace_are_killed():
    """A stopped sweep ends: a worker that answers SIGTERM ends by it, one that does not is killed after the
    grace, and the stop does not wait longer than that."""
    import multiprocessing as mp
    import time

    from fracture.pipeline.sweep import stop_workers

    ctx = mp.get_context("spawn")
    procs = []
    for target in (_worker_that_stops, _deaf_worker):
        ready = ctx.Event()
        procs.append(ctx.Process(target=target, args=(ready,)))
        procs[-1].start()
        assert ready.wait(60)
    signalled = []
    stop_workers(procs, grace=1.0, signalled=lambda: signalled.append(True))
    assert signalled == [True] and not any(p.is_alive() for p in procs)  # returned, with both ended
    assert procs[0].exitcode == -15 and procs[1].exitcode == -9  # SIGTERM ended one, SIGKILL the other


def test_export_and_render_of_a_sweep_name_one_of_its_points(local_sweep, tmp_path, capsys):
    _, out, _ = local_sweep
    first = out / "psi.stress_weight=0.2,seed=7"
    for args, verb in ((["export", str(out), "--out", str(tmp_path / "x.usdc")], "export"),
                       (["render", str(out), "--quiet", "--out", str(tmp_path / "r")], "name")):
        assert main(args) == 2
        err = capsys.readouterr().err
        assert err == f"fracref: error: {out}: a sweep, not a run; {verb} one of its points, e.g. {first}\n", err
    assert list(tmp_path.iterdir()) == []


def test_a_cluster_address_without_the_ray_backend_is_refused(local_sweep, tmp_path, capsys):
    config, _, _ = local_sweep
    rc = main(["sweep", str(config), "--grid", "seed=1,2", "--address", "auto", "--out", str(tmp_path / "a")])
    assert rc == 2 and not (tmp_path / "a").exists()
    assert capsys.readouterr().err == ("fracref: error: --address: got 'auto' with the local backend; expected it "
                                       "with --backend ray (the cluster to join)\n")

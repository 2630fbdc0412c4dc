"""The viewer: headless renders, the window under Xvfb (one subprocess each, with a timeout), cameras and inputs."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import CONFIGS

from fracture.pipeline import runner
from fracture.pipeline.config import load_config
from fracture.errors import InputError

HERE = Path(__file__).resolve().parent
# a small run with fields, iterations and a 6-frame animation of 14 pieces (a few seconds)
RUN_OVERRIDES = ["input.frames=6", "refine.max_triangles=4000", "refine.iterations=6", "grid.resolution=40",
                 "animate.check_samples=1000"]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("viewer") / "jello"
    runner.run(load_config(CONFIGS / "jello.yaml", RUN_OVERRIDES), out, progress=False)
    return out


def content_share(img: np.ndarray) -> float:
    """Share of pixels that differ from the corner (background) colour."""
    return float((np.abs(img.astype(int) - img[0, 0].astype(int)).sum(axis=2) > 30).mean())


def read(path) -> np.ndarray:
    import imageio.v3 as iio

    return iio.imread(path)[..., :3]


def video_frames(path) -> tuple[int, tuple[int, int]]:
    import imageio_ffmpeg

    gen = imageio_ffmpeg.read_frames(str(path))
    meta = gen.__next__()
    n = sum(1 for _ in gen)
    return n, tuple(meta["size"])


def _cli(args, timeout=300):
    env = dict(os.environ)
    env.pop("DISPLAY", None)
    return subprocess.run([sys.executable, "-m", "fracref", *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


def test_the_window_without_a_display_says_to_render(run_dir):
    r = _cli(["view", str(run_dir)])
    assert r.returncode == 2 and r.stderr == ("fracref: error: view: no display to open a window on (DISPLAY is not "
                                              "set); `fracref render RUN` makes the same pictures without one\n")


def test_headless_renders_are_figures_and_videos(run_dir, tmp_path):
    r = _cli(["render", str(run_dir), "--what", "iterations", "--what", "animation", "--out", str(tmp_path),
              "--width", "320", "--height", "240", "--fps", "4", "--image-seconds", "0.5", "--hold", "1.5",
              "--quiet"])
    assert r.returncode == 0, r.stderr[-2000:]
    its = sorted(tmp_path.glob("iterations_psi_*.png"))
    iterations = json.loads((run_dir / "manifest.json").read_text())["counts"]["iterations"]
    assert iterations >= 2 and len(its) == iterations + 1  # the coarse surface and every iteration
    first, last = read(its[0]), read(its[-1])
    assert first.shape == (240, 320, 3)
    assert content_share(first) > 0.03 and content_share(last) > 0.03
    assert np.abs(first.astype(int) - last.astype(int)).mean() > 1.0  # another iteration, another image
    # each image 0.5 s at 4 frames a second, the last held 1.5 s more
    assert video_frames(tmp_path / "iterations_psi.mp4") == (2 * (iterations + 1) + 6, (320, 240))
    frames = sorted(tmp_path.glob("animation_*.png"))
    assert len(frames) == 6 and content_share(read(frames[-1])) > 0.05
    assert video_frames(tmp_path / "animation.mp4") == (2 * 6 + 6, (320, 240))


def test_headless_slices_follow_the_field_and_level(run_dir, tmp_path):
    r = _cli(["render", str(run_dir), "--what", "slices", "--out", str(tmp_path / "a"), "--width", "320",
              "--height", "240", "--quiet"])
    assert r.returncode == 0, r.stderr[-2000:]
    r = _cli(["render", str(run_dir), "--what", "slices", "--out", str(tmp_path / "b"), "--width", "320",
              "--height", "240", "--level", "3", "--quiet"])
    assert r.returncode == 0, r.stderr[-2000:]
    a, b = sorted((tmp_path / "a").glob("*.png")), sorted((tmp_path / "b").glob("*.png"))
    assert len(a) == len(b) == 9
    assert content_share(read(a[4])) > 0.1
    assert (read(a[4])[2, 2] == 255).all()  # a white background (the renderer's grading made it 248)
    assert np.abs(read(a[0]).astype(int) - read(a[8]).astype(int)).mean() > 1.0  # another offset
    assert np.abs(read(a[4]).astype(int) - read(b[4]).astype(int)).mean() > 0.5  # a smoother level


def test_render_rejects_bad_requests_clearly(run_dir, tmp_path):
    r = _cli(["render", str(run_dir), "--what", "slices", "--width", "333", "--out", str(tmp_path)])
    assert r.returncode == 2 and "width must be an even number" in r.stderr
    r = _cli(["render", str(run_dir), "--what", "slices", "--field", "strength", "--out", str(tmp_path)])
    assert r.returncode == 2 and "field must be one of psi, zeta, xi" in r.stderr
    r = _cli(["render", str(tmp_path / "nothing"), "--what", "slices"])
    assert r.returncode == 2 and "no such run directory" in r.stderr
    r = _cli(["render", str(run_dir), "--what", "compare", "--frame", "0", "--out", str(tmp_path)])
    assert r.returncode == 2 and "--frame counts frames from 1; got 0" in r.stderr, r.stderr
    r = _cli(["render", str(run_dir), "--what", "slices", "--frame", "999", "--out", str(tmp_path)])
    assert r.returncode == 2 and "frame must be in 1..6, got 999" in r.stderr, r.stderr
    for flag, value, words in (("--fps", "0", "--fps must be in 1..240 video frames a second, got 0"),
                               ("--image-seconds", "0", "--image-seconds must be in (0, 60], got 0.0"),
                               ("--hold", "-1", "--hold must be in 0..60 seconds, got -1.0")):
        r = _cli(["render", str(run_dir), "--what", "slices", flag, value, "--out", str(tmp_path)])
        assert r.returncode == 2 and r.stderr == f"fracref: error: {words}\n", r.stderr
    assert not list(tmp_path.glob("*.png"))


@pytest.mark.parametrize("args, words", [
    (["render", "{run}", "--width", "333"], "width must be an even number"),
    (["render", "{run}", "--field", "strength"], "field must be one of psi, zeta, xi"),
    (["render", "{run}", "--what", "compare", "--frame", "999"], "frame must be in 1..6, got 999"),
    (["render", "{nothing}"], "no such run directory"),
    (["view", "{run}"], "no display to open a window on"),
])
def test_a_wrong_request_is_refused_before_the_renderer_loads(run_dir, tmp_path, args, words):
    """A bad flag or run directory is said without Open3D (seconds of imports) or the pipeline's stages
    loaded: the refusal is all the command does."""
    if args[0] == "view" and not sys.platform.startswith("linux"):
        pytest.skip("the window's display test is Linux's (DISPLAY, WAYLAND_DISPLAY)")
    args = [a.format(run=run_dir, nothing=tmp_path / "nothing") for a in args]
    code = ("import contextlib, io, json, sys\nfrom fracref.cli import main\nerr = io.StringIO()\n"
            f"with contextlib.redirect_stderr(err):\n    rc = main({args!r})\n"
            "print(json.dumps([rc, err.getvalue(), sorted(m for m in ('open3d', 'fracture.pipeline.runner', "
            "'fracture.refine.engine', 'viewer.render', 'viewer.looks') if m in sys.modules)]))")
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    rc, said, loaded = json.loads(r.stdout.strip().splitlines()[-1])
    assert rc == 2 and words in said and "Traceback" not in said, said
    assert loaded == [], loaded


@pytest.mark.parametrize("damaged, what", [("fields/psi.npy", "slices"), ("refined/iterations.npz", "iterations"),
                                           ("pieces/piece_000.ply", "animation")])
def test_a_damaged_run_file_is_named_in_one_line_and_the_render_leaves_nothing(run_dir, tmp_path, damaged, what):
    """A run's file cut short (a copy in part, a disk that filled): one line naming it, no traceback, and the
    render's folders, made for it, go again."""
    run = tmp_path / "run"
    shutil.copytree(run_dir, run)
    path = run / damaged
    path.write_bytes(path.read_bytes()[:300])
    out = tmp_path / "renders" / "deep"
    r = _cli(["render", str(run), "--what", what, "--width", "160", "--height", "120", "--quiet", "--out", str(out)])
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert damaged in r.stderr.strip().splitlines()[-1] and "frames have been written" not in r.stderr, r.stderr
    assert not (tmp_path / "renders").exists()


@pytest.mark.parametrize("rel, content, words", [
    ("fields/psi.npy", None, "fields/psi.npy holds values of shape (3, 3), expected the grid's"),
    ("manifest.json", "[]", "manifest.json: holds a JSON list; expected a run's manifest"),
])
def test_a_run_file_of_another_kind_is_named_in_one_line_and_the_render_leaves_nothing(run_dir, tmp_path, rel,
                                                                                        content, words):
    """A run's file whole but not what the run wrote (another run's field, a manifest that is a list)."""
    run = tmp_path / "run"
    shutil.copytree(run_dir, run)
    if content is None:
        np.save(run / rel, np.zeros((3, 3)))
    else:
        (run / rel).write_text(content)
    out = tmp_path / "renders" / "deep"
    r = _cli(["render", str(run), "--what", "slices", "--width", "160", "--height", "120", "--quiet", "--out", str(out)])
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert words in r.stderr.strip().splitlines()[-1], r.stderr
    assert not (tmp_path / "renders").exists()


def test_render_without_what_renders_what_a_run_stopped_early_has(small_config, tmp_path):
    coarse, refined = tmp_path / "coarse", tmp_path / "refined"
    runner.run(load_config(small_config), coarse, until="coarse", progress=False)
    runner.run(load_config(small_config, ["refine.iterations=2"]), refined, until="refine", progress=False)
    r = _cli(["render", str(coarse), "--quiet"])
    assert r.returncode == 2 and "nothing to render: the run stopped after its coarse stage" in r.stderr, r.stderr
    r = _cli(["render", str(coarse), "--what", "slices", "--quiet"])
    assert r.returncode == 2 and "no fields to render slices of" in r.stderr, r.stderr
    assert not (coarse / "renders").exists()
    r = _cli(["render", str(refined), "--width", "160", "--height", "120", "--quiet"])
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.startswith("slices: 9 images") and "iterations: 3 images" in r.stdout, r.stdout
    assert "animation: not in this run" in r.stdout
    assert "OpenGL" not in r.stdout + r.stderr and "EGL" not in r.stdout + r.stderr  # --quiet: no greetings
    assert sorted(p.name for p in (refined / "renders").glob("*.mp4")) == ["iterations_psi.mp4", "slices_psi_z.mp4"]
    r = _cli(["render", str(refined), "--what", "animation"])
    assert r.returncode == 2 and "no animation to render" in r.stderr


def _window(scenario: str, run_dir: Path, out: Path) -> dict:
    xvfb = shutil.which("xvfb-run")
    if xvfb is None:
        pytest.fail("xvfb-run is missing: `make system-deps` installs it")
    r = subprocess.run([xvfb, "-a", "-s", "-screen 0 1920x1080x24", sys.executable, str(HERE / "gui_driver.py"),
                        scenario, str(run_dir), str(out)], capture_output=True, text=True, timeout=240,
                       cwd=HERE.parent)
    assert r.returncode == 0, (r.stdout[-2000:], r.stderr[-3000:])
    return json.loads((out / "result.json").read_text())


@pytest.mark.gui
def test_the_window_shows_three_panels_that_follow_their_controls(run_dir, tmp_path):
    res = _window("panels", run_dir, tmp_path)
    for shown, refit in res["camera_refit"]:
        assert shown == pytest.approx(refit, rel=1e-6, abs=1e-9)
    assert res["errors"] == []
    panels = [read(p) for p in res["initial"]]
    for img in panels:
        assert content_share(img) > 0.03
    diff = lambda a, b: np.abs(read(a).astype(int) - read(b).astype(int)).mean()  # noqa: E731
    assert diff(res["initial"][1], res["iteration1"]) > 0.5  # iteration slider
    assert diff(res["initial"][2], res["frame_last"]) > 0.5  # frame slider
    assert diff(res["initial"][0], res["offset"]) > 0.5  # slice offset
    assert diff(res["offset"], res["zeta"]) > 0.5  # field
    shot = read(res["screenshot"])
    assert shot.shape == (360, 640, 3) and content_share(shot) > 0.05  # exactly the size asked for
    assert video_frames(res["video"]) == (res["frames"], (640, 360))


@pytest.mark.gui
def test_dragging_turns_each_panel_about_its_subject_and_exports_leave_the_cameras(run_dir, tmp_path):
    res = _window("navigate", run_dir, tmp_path)
    assert res["errors"] == []

    def in_view(panel):
        assert panel["share"] > 0.02, panel
        assert abs(panel["centre"][0] - 0.5) < 0.2 and abs(panel["centre"][1] - 0.5) < 0.2, panel

    for key in ("initial", "after_drag", "linked", "after_export", "top"):
        for panel in res[key]:
            in_view(panel)
    assert res["moved"] != res["initial"]  # the drags turned the cameras
    # linked: every panel looks the same way
    F = np.array(res["linked_forward"])
    assert np.allclose(F, F[0], atol=1e-4)
    # exports leave every camera as it was (up to the float rounding of its aspect ratio)
    assert np.allclose(res["cameras_after_export"], res["cameras_before_export"], rtol=1e-5, atol=1e-6)
    assert np.allclose(res["after_reset_key"], res["fresh"], rtol=1e-5, atol=1e-6)  # R, over panel 3
    assert content_share(read(res["screenshot"])) > 0.05


@pytest.mark.gui
def test_rerun_in_the_window_gives_a_new_result_without_freezing_it(run_dir, tmp_path):
    res = _window("rerun", run_dir, tmp_path)
    assert not res["worker_at_open"]
    assert len(res["rerun_dirs"]) == 1 and res["shown"] == res["rerun_dirs"][0]
    assert Path(res["rerun_dirs"][0], "manifest.json").is_file() and Path(run_dir, "manifest.json").is_file()
    assert res["stress_weight"] == 0.0 and not res["same_surface"]
    assert res["live_updates"] >= 1  # iterations were drawn while the worker ran
    assert res["ticks"] >= 2  # the window kept ticking while the worker ran (no wall-clock bound)
    saved = load_config(res["saved"])
    assert saved.psi.stress_weight == 0.0
    # the invalid step was reported in the window, and nothing ran
    assert any("refine.step" in e for e in res["errors"])


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory):
    """A two-point sweep of a small config (stress weights 0.2 and 2)."""
    from conftest import small_config_file
    from fracture.pipeline.sweep import run_sweep

    base = tmp_path_factory.mktemp("viewer-sweep")
    run_sweep(small_config_file(base), {"psi.stress_weight": [0.2, 2.0]}, base / "sweep", progress=False)
    return base / "sweep"


@pytest.mark.gui
def test_a_sweep_opens_with_its_points_to_choose_and_flip(sweep_dir, tmp_path):
    res = _window("sweep", sweep_dir, tmp_path)
    a, b = res["points"]
    assert res["errors"] == []
    # the first point, then the chosen second, then F over a panel flips back and forth
    assert res["shown"] == [a, b, a, b] and res["selected"] == 1
    assert res["title"][1].endswith("psi.stress_weight=2.0")
    assert res["stress_weight_edit"] == 2.0  # the side panel holds the shown point's parameters
    assert res["cameras_kept"]  # compared from the same cameras
    one, two = (read(p) for p in res["shots"])
    assert content_share(one) > 0.03 and content_share(two) > 0.03
    assert np.abs(one.astype(int) - two.astype(int)).mean() > 0.5  # another surface, other colours


def test_camera_fits_every_point_in_the_picture():
    from viewer.looks import frame_points

    rng = np.random.default_rng(0)
    for aspect in (0.5, 1.0, 16 / 9):
        P = rng.normal(size=(200, 3)) * [3.0, 1.0, 0.2]
        pose = frame_points(P, aspect, margin=1.0)
        f = pose.center - pose.eye
        f /= np.linalg.norm(f)
        right = np.cross(f, pose.up)
        C = P - pose.eye
        depth = C @ f
        assert (depth > 0).all()
        tan_v = np.tan(np.radians(pose.fov) / 2)
        x = np.abs(C @ right) / depth / (tan_v * aspect)
        y = np.abs(C @ pose.up) / depth / tan_v
        assert max(x.max(), y.max()) == pytest.approx(1.0, abs=1e-9)  # tight: the farthest point on the edge
        # centred: on the tight axis the points reach both edges
        sx, sy = (C @ right) / depth / (tan_v * aspect), (C @ pose.up) / depth / tan_v
        tight = sx if x.max() > y.max() else sy
        assert tight.min() == pytest.approx(-1.0, abs=1e-9) and tight.max() == pytest.approx(1.0, abs=1e-9)


def test_run_data_and_view_say_what_is_wrong(run_dir, tmp_path):
    from viewer.data import RunData
    from viewer.looks import View

    with pytest.raises(InputError, match="no manifest.json"):
        RunData(tmp_path)
    run = RunData(run_dir)
    with pytest.raises(InputError, match="axis must be x, y or z"):
        View(axis="w").check(run)
    with pytest.raises(InputError, match="pyramid level must be in 0..4"):
        View(level=9).check(run)
    with pytest.raises(InputError, match="frame must be in 1..6"):
        run.pieces_at(6)
    assert View().check(run).iteration == len(run.iterations) - 1


def test_tunables_round_trip_through_the_config(run_dir):
    from viewer.side import set_key, tunables
    from viewer.data import RunData

    cfg = RunData(run_dir).config
    keys = dict(tunables(cfg))
    assert {"seed", "psi.stress_weight", "refine.step", "pyramid.levels"} <= set(keys)
    assert any(k.startswith("strength.layers.0.") for k in keys)
    set_key(cfg, "strength.layers.0.weight", 0.5)
    assert cfg["strength"]["layers"][0]["weight"] == 0.5


def test_a_rendered_slice_has_its_colour_bar_colours(run_dir, tmp_path):
    # in a child process with no display (EGL): the slice alone, seen face-on, every pixel's
    # colour against the colour bar's colour of the field value drawn there
    code = f"""
import json, sys
import numpy as np
from viewer.render import Renderer
from viewer.data import RunData
from viewer.looks import FIELD_CMAPS, View, prepare, set_slice, slice_pose
from fields.colormap import colormap, to_uint8
from fields.slices import axis_slice
run = RunData({str(run_dir)!r})
view = View(field="psi", axis="z", offset=0.5).check(run)
r = Renderer(400, 400)
prepare(r.scene)
lo, hi = set_slice(r.scene, run, view)
pose = slice_pose(run, view, 1.0)
pose.eye = pose.center + np.linalg.norm(pose.eye - pose.center) * np.array([0, 0, 1.0])
pose.up = np.array([0, 1.0, 0])
img = r.image(pose).astype(int)
bar = to_uint8(colormap(np.linspace(0, 1, 1024), FIELD_CMAPS["psi"], 0, 1)).astype(int)
from scipy.ndimage import binary_erosion
inside = binary_erosion(np.abs(img - img[0, 0]).sum(axis=2) > 30, iterations=3)  # not the edge's blend
px = img[inside]
from scipy.spatial import cKDTree
nearest = cKDTree(bar).query(px, p=np.inf)[0]  # the largest channel's difference to the nearest bar colour
json.dump({{"pixels": int(inside.sum()), "p95": float(np.percentile(nearest, 95)),
            "median": float(np.median(nearest))}}, sys.stdout)
"""
    env = dict(os.environ)
    env.pop("DISPLAY", None)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env,
                       cwd=HERE.parent)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(r.stdout.strip().splitlines()[-1])
    assert res["pixels"] > 10000
    # within a few units per channel of a colour of the bar (they were 70 units off, encoded twice)
    assert res["median"] <= 4 and res["p95"] <= 6, res


def test_exports_are_numbered_and_never_overwrite(tmp_path):
    from viewer.exports import numbered

    first = numbered(tmp_path / "renders", "screenshot_all_panels", ".png")
    assert first.name == "screenshot_all_panels_001.png"
    first.parent.mkdir()
    first.write_bytes(b"1")
    (tmp_path / "renders" / "screenshot_all_panels_002.png").write_bytes(b"2")
    assert numbered(tmp_path / "renders", "screenshot_all_panels", ".png").name == "screenshot_all_panels_003.png"
    assert numbered(tmp_path / "renders", "window_animation", ".mp4").name == "window_animation_001.mp4"


@pytest.mark.gui
def test_saved_views_come_back_and_the_window_fits_its_default_size(run_dir, tmp_path):
    from viewer.state import read_view_file

    res = _window("views", run_dir, tmp_path)
    assert res["errors"] == []
    # every control inside the window (at the default 1800 x 900 they ran off the right edge)
    x0, y0, w, h = res["content"]
    for name, (x, y, fw, fh) in res["frames"].items():
        assert fw > 0 and fh > 0 and x >= x0 and x + fw <= x0 + w, (name, (x, y, fw, fh), w)
        if name not in ("shot", "transparent"):  # the side panel scrolls; the rest must be in the window
            assert y + fh <= y0 + h, (name, (x, y, fw, fh), h)
    for x, y, fw, fh in res["panels"]:
        assert y + fh <= y0 + h
    # a second window opened on the saved view shows the same things from the same cameras
    first, second = res["views"]
    assert first == second and first["offset"] == pytest.approx(0.3) and first["cutaway"]
    assert np.allclose(res["cameras_second"], res["cameras_first"], rtol=1e-5, atol=1e-6)
    # Save config holds the same view, and the pipeline reads the file
    cfg = load_config(res["saved_config"])
    state = read_view_file(res["saved_config"])
    assert cfg.view.iteration == first["iteration"] and state.view == read_view_file(tmp_path / "view.yaml").view
    compare = read(res["compare"])
    assert compare.shape == (360, 640, 3)
    assert content_share(compare[:, :320]) > 0.05 and content_share(compare[:, 320:]) > 0.05
    import imageio.v3 as iio

    rgba = iio.imread(res["transparent"])
    assert rgba.shape == (360, 640, 4) and rgba[2, 2, 3] == 0 and (rgba[..., 3] == 255).mean() > 0.05
    # idle, the window uses next to no processor time
    assert res["idle_cpu"] < 0.25, res["idle_cpu"]


def test_compare_turntable_and_transparent_supersampled_figures(run_dir, tmp_path):
    import imageio.v3 as iio

    r = _cli(["render", str(run_dir), "--what", "compare", "--what", "turntable", "--out", str(tmp_path),
              "--width", "320", "--height", "240", "--fps", "4", "--turntable-seconds", "2", "--transparent",
              "--supersample", "2", "--quiet"])
    assert r.returncode == 0, r.stderr[-2000:]
    n = RunData_frames(run_dir)
    rgba = iio.imread(tmp_path / f"compare_frame_{n:04d}.png")  # the last frame by default: the pieces apart
    assert rgba.shape == (240, 320, 4)
    alpha = rgba[..., 3]
    assert alpha[0, 0] == 0 and alpha[0, -1] == 0  # the sky is transparent, the ground and pieces are not
    left, right = rgba[:200, :160, :3].astype(int), rgba[:200, 160:, :3].astype(int)
    assert (alpha[:200, :160] == 255).mean() > 0.1 and (alpha[:200, 160:] == 255).mean() > 0.1
    assert np.abs(left - right).mean() > 0.5  # coarse and refined pieces differ
    assert video_frames(tmp_path / f"turntable_frame_{n:04d}.mp4") == (8, (320, 240))


def RunData_frames(run_dir) -> int:
    from viewer.data import RunData

    return RunData(run_dir).n_frames


def test_render_follows_a_view_file_and_refuses_a_bad_one(run_dir, tmp_path):
    from viewer.data import RunData
    from viewer.looks import CameraPose, View, scene_box
    from viewer.state import ViewState, write_view_file

    lo, hi = scene_box(RunData(run_dir))
    c = 0.5 * (lo + hi)
    below = CameraPose(c, c - np.array([0.0, 0.0, 3.0]) * np.linalg.norm(hi - lo), np.array([0.0, 1.0, 0.0]), 30.0)
    write_view_file(tmp_path / "view.yaml", ViewState(View(field="zeta", offset=0.3), {"material": below}))
    args = ["--what", "slices", "--width", "320", "--height", "240", "--quiet"]
    r = _cli(["render", str(run_dir), "--out", str(tmp_path / "a"), *args])
    assert r.returncode == 0, r.stderr[-2000:]
    r = _cli(["render", str(run_dir), "--out", str(tmp_path / "b"), "--camera", str(tmp_path / "view.yaml"), *args])
    assert r.returncode == 0, r.stderr[-2000:]
    assert [p.name for p in sorted((tmp_path / "b").glob("*.png"))][0] == "slices_zeta_z_0000.png"
    a, b = read(tmp_path / "a" / "slices_psi_z_0004.png"), read(tmp_path / "b" / "slices_zeta_z_0004.png")
    assert np.abs(a.astype(int) - b.astype(int)).mean() > 1.0
    (tmp_path / "bad.yaml").write_text("view:\n  cameras:\n    material: {eye: [0, 0, 1], center: [0, 0, 1], "
                                       "up: [0, 1, 0]}\n")
    r = _cli(["render", str(run_dir), "--out", str(tmp_path / "c"), "--camera", str(tmp_path / "bad.yaml"), *args])
    assert r.returncode == 2 and "bad.yaml" in r.stderr and "view.cameras.material" in r.stderr
    assert "same point" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "c").exists()


def test_view_sections_round_trip_and_name_what_is_wrong(tmp_path):
    from fracture.errors import ConfigError
    from viewer.looks import CameraPose, View
    from viewer.state import ViewState, from_section, read_view_file, write_view_file

    pose = CameraPose(np.array([0.1, 0.2, 0.3]), np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.0, 1.0]), 40.0)
    state = ViewState(View(field="xi", axis="x", offset=0.25, level=2, iteration=3, color_by="speed", frame=4,
                           overlay_coarse=True, cutaway=True), {"material": None, "iterations": pose, "animation": None})
    back = read_view_file(write_view_file(tmp_path / "v.yaml", state))
    assert back.view == state.view and back.cameras["material"] is None
    got = back.cameras["iterations"]
    assert np.allclose(got.eye, pose.eye) and np.allclose(got.center, pose.center) and got.fov == 40.0
    assert from_section(None, "x").view == View(iteration=-1)
    cases = [({"field": "strength"}, "view.field", "one of 'psi', 'zeta', 'xi'"),
             ({"cameras": {"animation": {"eye": [0, 0, 1]}}}, "view.cameras.animation", "all three"),
             ({"cameras": {"animation": {"eye": [0, 0, 1], "center": [0, 0, 0], "up": [0, 0, 2]}}},
              "view.cameras.animation.up", "along the viewing direction"),
             ({"frame": 0}, "view.frame", ">= 1"), ({"zoom": 2}, "view.zoom", "unknown key")]
    for section, key, words in cases:
        with pytest.raises(ConfigError) as e:
            from_section(section, "my_view.yaml")
        assert key in str(e.value) and words in str(e.value) and "my_view.yaml" in str(e.value)
    (tmp_path / "plain.yaml").write_text("seed: 3\n")
    with pytest.raises(ConfigError, match="no view: section"):
        read_view_file(tmp_path / "plain.yaml")


def test_figures_keep_the_picture_whole_and_label_the_bar_with_round_ticks():
    from viewer import annotate
    from viewer.annotate import Bar, nice_ticks

    rng = np.random.default_rng(1)
    for lo, hi in ((-0.27, 0.43), (0.0, 1.0), (3.1, 3.15), (-1200.0, 80.0), (0.2, 0.2000001)):
        t = nice_ticks(lo, hi)
        assert 2 <= len(t) <= 6 and t.min() >= lo - 1e-12 and t.max() <= hi + 1e-12
        step = np.diff(t)
        assert np.allclose(step, step[0])
        mantissa = step[0] / 10 ** np.floor(np.log10(step[0]) + 1e-6)
        assert any(np.isclose(mantissa, m, rtol=1e-4) for m in (1, 2, 2.5, 5))
        labels = annotate.tick_labels(t)
        assert len(set(labels)) == len(labels) and "-0" not in labels  # each tick its own label
    for width, height, bar, caption in ((640, 360, True, True), (320, 240, False, True), (1280, 720, True, False)):
        lay = annotate.layout(width, height, bar, caption)
        pw, ph = lay.picture
        for channels in (3, 4):
            picture = rng.integers(0, 256, (ph, pw, channels), dtype=np.uint8)
            fig = annotate.compose(picture, lay, Bar("viridis", -0.27, 0.43, "psi") if bar else None,
                                   "iteration 12 / 40, 123,456 triangles, E = 0.7005" if caption else None)
            assert fig.shape == (height, width, channels)
            assert (fig[:ph, :pw] == picture).all()  # nothing drawn over the picture
            if bar:
                strip = fig[:ph, pw:, :3].astype(int)
                assert (np.abs(strip - 255).sum(axis=2) > 0).mean() > 0.02  # the bar and its ticks are there


def test_videos_keep_the_pace_of_their_images():
    from viewer.media import frame_counts

    assert frame_counts(5, 0.5, 4) == [2] * 5
    for n, seconds, fps in ((40, 1 / 24, 30), (40, 1 / 30, 24), (7, 0.25, 10), (100, 1 / 60, 24)):
        counts = frame_counts(n, seconds, fps)
        assert len(counts) == n and counts[0] >= 1 and min(counts) >= 0
        assert abs(sum(counts) - n * seconds * fps) <= 1  # the video lasts as long as the images
        ends = np.cumsum(counts)
        assert np.all(np.abs(ends - np.arange(1, n + 1) * seconds * fps) <= 1)  # and never drifts


def test_open3d_loads_its_machine_learning_package_on_first_use_when_deferred():
    """`fracref view` and `render` import Open3D without Open3D-ML (scikit-learn): it loads when used."""
    bundled = subprocess.run([sys.executable, "-c", "import open3d; print(open3d._build_config['BUNDLE_OPEN3D_ML'])"],
                             capture_output=True, text=True, timeout=300).stdout.strip()
    if bundled != "True":
        pytest.skip("this Open3D has no Open3D-ML to defer")
    code = ("import sys\n"
            "from viewer.lazy_open3d import defer_open3d_ml\n"
            "assert defer_open3d_ml()\n"
            "import open3d\n"
            "import viewer.render\n"
            "assert 'sklearn' not in sys.modules and 'open3d._ml3d' not in sys.modules\n"
            "open3d.geometry.TriangleMesh.create_box()\n"
            "assert open3d.ml.datasets.SemanticKITTI is not None\n"
            "assert 'sklearn' in sys.modules\n"
            "assert not defer_open3d_ml()\n"  # Open3D is there: nothing changes
            "print('ok')\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]
    plain = subprocess.run([sys.executable, "-c", "import sys, viewer.render; print('sklearn' in sys.modules)"],
                           capture_output=True, text=True, timeout=300)
    assert plain.stdout.strip() == "True", plain.stderr[-2000:]  # as a library, the viewer changes nothing

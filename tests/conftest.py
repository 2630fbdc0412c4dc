"""Shared fixtures: tiny hand-built meshes and small configs."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest

from fracture.io.obj import write_obj
from fracture.mesh.primitives import box, sheet

REPO = Path(__file__).resolve().parents[1]
CONFIGS = REPO / "configs"
SAMPLE = REPO / "examples" / "blender_cellfracture_cube8"  # the Blender sample, shipped
# the five built-in scenes and the Blender sample
SCENE_CASES = ["bunny", "branch", "wall", "clay", "jello", "blender_cube8"]
# triangle budgets of the quick scene runs: the sample's coarse surface (contoured from its pieces) has 6K
BUDGETS = {"blender_cube8": 15000}
# The test files that take longest, longest first (seconds of one file on one worker, measured on the
# 2-core development machine). `make test` has xdist hand out whole files in collection order
# (--no-loadscope-reorder; by default it orders them by their number of tests, and the one-test files,
# the wheel's 100 s among them, came last), so these are collected first and spread over the workers,
# and the many short files fill the gaps (745 s against 647 s of work per worker before, in 752 s of
# wall time; 674 s and 672 s after, in 682 s).
LONGEST_FILES = ["test_cellfracture_corpus.py",  # 376
                 "test_viewer.py",  # 271
                 "test_wheel.py",  # 99
                 "test_runner.py",  # 97
                 "test_animate.py",  # 76
                 "test_import.py",  # 75
                 "test_readme.py",  # 72
                 "test_usd.py",  # 56
                 "test_process.py",  # 41
                 "test_viewer_lifetime.py"]  # 37


def pytest_collection_modifyitems(items):
    """The longest files first (:data:`LONGEST_FILES`), the others after them in their usual order."""
    rank = {name: i for i, name in enumerate(LONGEST_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


def random_cuts_asked() -> str:
    """``FRACREF_RANDOM_CUTS``: "all" or a number of random cases to add (tests/test_random_cuts.py)."""
    import os

    asked = os.environ.get("FRACREF_RANDOM_CUTS", "0").strip()
    if asked != "all" and not asked.isdigit():
        raise pytest.UsageError(f"FRACREF_RANDOM_CUTS={asked!r}: expected 'all' or a number of random cases to "
                                "add (0, 1, 2, ...)")
    return asked


def pytest_configure(config):
    """Stale compiled kernels are cleared once, by the main process (not by each xdist worker); the tests
    run the parallel kernels on numba's work queue, whose threads sleep between kernels (the command
    line's GNU OpenMP keeps them spinning, and with an xdist worker per core they would take the other
    worker's time). Set in the environment, the choice reaches the xdist workers and the processes the
    tests start, and fracture.process.prepare_process keeps it; commands the tests run in processes of
    their own (fracref run, sweeps) choose it too."""
    import os

    import numba

    random_cuts_asked()  # a wrong value stops the session in one line, not at the test file's collection
    os.environ["NUMBA_THREADING_LAYER"] = "workqueue"
    numba.config.THREADING_LAYER = "workqueue"
    if not hasattr(config, "workerinput"):
        from fracture.refine import clear_stale_numba_cache

        clear_stale_numba_cache()


def scene_config(name: str, overrides: list[str]) -> dict:
    """The config of a scene case with ``overrides``; built-in scenes get 8 frames, the sample keeps its own."""
    from fracture.pipeline.config import load_config

    return load_config(CONFIGS / f"{name}.yaml", overrides + ([] if name == "blender_cube8" else ["input.frames=8"]))


def mesh_area(V, F):
    """Total area of a triangle mesh."""
    return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()


def grid_sheet(n, z, shift=0.0):
    """An n x n grid of the unit square at height z (moved by ``shift`` in x, 0.7 of it in y), two
    triangles per cell."""
    x, y = np.meshgrid(np.linspace(0, 1, n) + shift, np.linspace(0, 1, n) + 0.7 * shift, indexing="ij")
    V = np.column_stack([x.ravel(), y.ravel(), np.full(n * n, z)])
    i = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    return V, np.concatenate([np.stack([i, i + n, i + 1], 1), np.stack([i + 1, i + n, i + n + 1], 1)])


def colliding_vertices(X0, X1, F, eta):
    """Mask of the vertices of every vertex-triangle and edge-edge pair of triangles ``F`` (sharing no
    vertex) that meets while the vertices move from ``X0`` to ``X1``, each pair tested: the reference
    for the culled searches."""
    from fracture.refine.collide import edge_edge_hit, vertex_triangle_hit
    E = np.unique(np.sort(np.stack([F, np.roll(F, -1, 1)], 2).reshape(-1, 2), 1), axis=0)
    hit = np.zeros(len(X0), bool)
    times = np.empty(4)
    P = lambda i: (tuple(X0[i]), tuple(X1[i]))  # noqa: E731
    for v in np.unique(F):
        for a, b, c in F:
            if v not in (a, b, c) and vertex_triangle_hit(*P(v), *P(a), *P(b), *P(c), eta * eta, times):
                hit[[v, a, b, c]] = True
    for i, (p, q) in enumerate(E):
        for r, s in E[i + 1:]:
            if len({p, q, r, s}) == 4 and edge_edge_hit(*P(p), *P(q), *P(r), *P(s), eta * eta, times):
                hit[[p, q, r, s]] = True
    return hit


def write_slab_meshes(folder: Path):
    """A 2 x 1 x 0.5 box and a wavy cut through it, written as OBJ files."""
    V, F = box([0, 0, 0], [2, 1, 0.5], (8, 4, 2))
    SV, SF = sheet(lambda u, v: np.stack([0.9 + 0.2 * u + 0.05 * np.sin(4 * u), u, v], 1), (0, 1), (0, 0.5), 5, 3)
    write_obj(folder / "slab.obj", V, F)
    write_obj(folder / "cut.obj", SV, SF)
    return folder / "slab.obj", folder / "cut.obj"


@pytest.fixture
def slab_meshes(tmp_path):
    """:func:`write_slab_meshes` in the test's folder."""
    return write_slab_meshes(tmp_path)


@pytest.fixture
def small_config(tmp_path, slab_meshes):
    """A config file for a quick end-to-end run (relative mesh paths)."""
    return small_config_file(tmp_path)


def small_config_file(folder: Path) -> Path:
    """:func:`small_config`'s file, and its meshes, in ``folder`` (for fixtures of a wider scope)."""
    write_slab_meshes(folder)
    path = folder / "small.yaml"
    path.write_text(textwrap.dedent("""\
        name: small
        seed: 7
        input:
          exterior: slab.obj
          fracture: cut.obj
        grid:
          resolution: 20
        strength:
          layers:
            - kind: marble
              grain_frequency: 8.0
        pyramid:
          levels: 3
        """))
    return path


@pytest.fixture(autouse=True, scope="session")
def _private_stage_cache(tmp_path_factory):
    """Command-line runs in the tests (they use the stage cache by default) keep it in a folder of the test
    session's, not in the user's ~/.cache."""
    import os

    os.environ["FRACREF_CACHE_DIR"] = str(tmp_path_factory.mktemp("stage-cache"))
    yield

"""Shared fixtures: tiny hand-built meshes and small configs."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest

from fracture.primitives import box, sheet, write_obj

REPO = Path(__file__).resolve().parents[1]
CONFIGS = REPO / "configs"
SHARED = REPO.parent / "shared" / "data" / "blender_cellfracture_cube8"
# the five built-in scenes and the Blender sample
SCENE_CASES = ["bunny", "branch", "wall", "clay", "jello", "blender_cube8"]


def scene_config(name: str, overrides: list[str]) -> dict:
    """The config of a scene case with ``overrides``; built-in scenes get 8 frames, the sample keeps its own."""
    from fracture.config import load_config

    if name == "blender_cube8" and not SHARED.is_dir():
        pytest.skip("the Blender sample is not beside the repository")
    return load_config(CONFIGS / f"{name}.yaml", overrides + ([] if name == "blender_cube8" else ["input.frames=8"]))


def mesh_area(V, F):
    """Total area of a triangle mesh."""
    return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()


@pytest.fixture
def slab_meshes(tmp_path):
    """A 2 x 1 x 0.5 box and a wavy cut through it, written as OBJ files."""
    V, F = box([0, 0, 0], [2, 1, 0.5], (8, 4, 2))
    SV, SF = sheet(lambda u, v: np.stack([0.9 + 0.2 * u + 0.05 * np.sin(4 * u), u, v], 1), (0, 1), (0, 0.5), 5, 3)
    write_obj(tmp_path / "slab.obj", V, F)
    write_obj(tmp_path / "cut.obj", SV, SF)
    return tmp_path / "slab.obj", tmp_path / "cut.obj"


@pytest.fixture
def small_config(tmp_path, slab_meshes):
    """A config file for a quick end-to-end run (relative mesh paths)."""
    path = tmp_path / "small.yaml"
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

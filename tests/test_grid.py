"""The field grid (fields/build.py grid_for): cubic cells, enough of them across a thin object."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fields.build import grid_for
from fields.grid import thinnest_extent


def _box(size, turn=(0.0, 0.0, 0.0)):
    corners = np.array(list(np.ndindex(2, 2, 2)), float) * size
    return Rotation.from_euler("xyz", turn, degrees=True).apply(corners)


@pytest.mark.parametrize("turn", [(0.0, 0.0, 0.0), (25.0, 40.0, 10.0)])
def test_a_thin_plank_gets_enough_nodes_across_turned_any_way(turn):
    V = _box([6.0, 0.8, 0.1], turn)
    assert thinnest_extent(V) == pytest.approx(0.1)
    grid = grid_for(V, 50, 0.05, min_across=8)
    assert np.allclose(grid.spacing, grid.spacing[0], rtol=0.01)  # cells close to cubes (whole counts)
    assert 0.1 / grid.spacing.max() >= 0.99 * 7  # eight nodes across the thickness: seven cells
    # without the rule: 50 nodes along the box's longest axis, less than two cells across the plank
    coarse = grid_for(V, 50, 0.05)
    assert max(coarse.shape) == 50 and 0.1 / coarse.spacing[0] < 2


def test_a_compact_object_and_explicit_shapes_are_as_asked():
    cube = _box([2.0, 2.0, 1.5])
    assert grid_for(cube, 50, 0.05, min_across=8).shape == grid_for(cube, 50, 0.05).shape == (50, 50, 39)
    plank = _box([6.0, 0.8, 0.1])
    assert grid_for(plank, [150, 50, 10], 0.05, min_across=8).shape == (150, 50, 10)


def test_the_fields_package_loads_its_modules_when_their_names_are_asked_for():
    """``fields.errors`` or ``fields.grid`` alone (the command line's config and error paths) load neither
    SciPy nor numba; every name the package lists resolves to its module's."""
    import json
    import subprocess
    import sys

    code = ("import json, sys\nimport fields.errors, fields.grid\nlight = [m for m in ('scipy', 'numba') if m in "
            "sys.modules]\nimport fields\nnames = {n: getattr(fields, n).__module__ for n in fields.__all__ "
            "if hasattr(getattr(fields, n), '__module__')}\nprint(json.dumps([light, names, 'KINDS' in dir(fields)]))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    light, names, listed = json.loads(r.stdout)
    assert light == [] and listed
    assert names["Grid"] == "fields.grid" and names["StrengthPyramid"] == "fields.pyramid"
    assert names["build_fields"] == "fields.build" and names["trilinear"] == "fields.interpolate"
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        import fields

        fields.nothing  # noqa: B018

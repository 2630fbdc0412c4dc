import numpy as np
import pytest

from fields.grid import Grid
from fields.strength import KINDS, UnitFrame, bricks, fibres, inclusions, load_volume, marble, radial, strength_field
from fracture.errors import InputError

BOUNDS = (np.array([0.0, 0.0, 0.0]), np.array([2.0, 1.0, 0.5]))
FRAME = UnitFrame(*BOUNDS)


def params(kind, **changes):
    defaults = {k: f.get_default(call_default_factory=True) for k, f in KINDS[kind][1].model_fields.items()
                if k not in ("kind", "weight")}
    return {**defaults, **changes}


def layer(kind, **changes):
    return {"kind": kind, "weight": 1.0, **params(kind, **changes)}


def sample_points(n=20000, seed=0):
    return np.random.default_rng(seed).uniform(BOUNDS[0], BOUNDS[1], (n, 3))


@pytest.mark.parametrize("kind", ["marble", "elongated", "fibres", "radial", "bricks", "inclusions"])
def test_every_kind_is_normalised_finite_and_seeded(kind):
    X = sample_points()
    a = strength_field(X, BOUNDS, [layer(kind)], seed=3)
    b = strength_field(X, BOUNDS, [layer(kind)], seed=3)
    assert np.all(np.isfinite(a)) and a.min() == 0.0 and a.max() == 1.0
    np.testing.assert_array_equal(a, b)
    if kind != "radial":  # radial has no randomness
        c = strength_field(X, BOUNDS, [layer(kind)], seed=4)
        assert np.abs(a - c).mean() > 1e-3


def test_marble_hard_region_is_strong_and_grainy():
    U = FRAME.to_unit(sample_points(40000))
    rng = lambda: np.random.default_rng(0)
    p = params("marble", grain_contrast=0.0, soft_contrast=0.0, edge_width=1e-3)
    z = marble(U, FRAME, rng(), **p)
    hard = np.isclose(z, p["hard_strength"])
    soft = np.isclose(z, p["soft_strength"])
    assert hard.sum() + soft.sum() > 0.95 * len(z)
    # The share of hard material follows hard_fraction (the veins are turbulent, so loosely).
    assert abs(hard.mean() - p["hard_fraction"]) < 0.12
    # With grain noise on, the hard region varies much faster than the soft one (measured at points
    # whose shifted copy stays in the same region, borders sharp: a step across a border is not grain).
    d = 0.004
    z_shift = marble(U + [d, 0, 0], FRAME, rng(), **p)
    hard &= np.isclose(z_shift, p["hard_strength"])
    soft &= np.isclose(z_shift, p["soft_strength"])
    grainy = params("marble", edge_width=1e-3)
    zg = marble(U, FRAME, rng(), **grainy)
    zg_shift = marble(U + [d, 0, 0], FRAME, rng(), **grainy)
    var_hard = np.abs(zg_shift - zg)[hard].mean()
    var_soft = np.abs(zg_shift - zg)[soft].mean()
    assert var_hard > 2 * var_soft


def test_elongated_noise_is_smoother_along_its_axis():
    X = sample_points(20000)
    f = lambda Y: strength_field(Y, BOUNDS, [layer("elongated", axis="y", stretch=8.0)], seed=1, normalize=False)
    base = f(X)
    d = 0.02
    along = np.abs(f(X + [0, d, 0]) - base).mean()
    across = np.abs(f(X + [d, 0, 0]) - base).mean()
    assert along < 0.4 * across


def test_fibres_are_bundles_with_weak_interfaces_each_weak_at_its_own_heights():
    """Along the axis a bundle's strength varies by its own noise (two bundles differ), across it the
    weakest places are the interfaces between bundles, and a point on an interface has the interface's
    strength whatever its height."""
    p = params("fibres", axis="x", bundle_size=0.1, interface_width=0.005, defect_length=0.05, defect_contrast=0.5)
    from scipy.spatial import cKDTree

    rng_seeds = np.random.default_rng(7)
    zeta = lambda P: fibres(P, FRAME, np.random.default_rng(7), **p)
    # the seeds the kind draws, to find the bundles and their interfaces
    extent = FRAME.extent[[1, 2]]
    n = np.ceil(extent / p["bundle_size"]).astype(int) + 3
    ii, jj = np.meshgrid(np.arange(n[0]) - 1.0, np.arange(n[1]) - 1.0, indexing="ij")
    lattice = np.column_stack([ii.ravel(), jj.ravel()])
    seeds = (lattice + rng_seeds.uniform(0.0, 1.0, lattice.shape)) * p["bundle_size"]
    inner = seeds[(seeds[:, 0] > 0.02) & (seeds[:, 0] < extent[0] - 0.02) & (seeds[:, 1] > 0.02)
                  & (seeds[:, 1] < extent[1] - 0.02)]
    a, b = inner[0], inner[int(np.argmin(np.linalg.norm(inner[1:] - inner[0], axis=1))) + 1]
    line = np.linspace(0.0, 1.9, 400)
    along = lambda yz: zeta(np.column_stack([line, np.tile(yz, (len(line), 1))]))
    za, zb = along(a), along(b)
    assert np.ptp(za) > 0.3 and np.ptp(zb) > 0.3  # weak and strong places along a bundle
    assert np.corrcoef(za, zb)[0, 1] < 0.5  # at other heights in the next bundle
    mid = 0.5 * (a + b)
    assert cKDTree(seeds).query(mid, k=2)[0][0] == pytest.approx(np.linalg.norm(mid - a))  # a, b nearest to mid
    zm = along(mid)
    np.testing.assert_allclose(zm, p["interface_strength"], atol=1e-6)  # the interface, all along
    assert zm.max() < np.minimum(za, zb).min()


def test_radial_is_soft_inside_and_hard_outside():
    U = np.array([[1.0, 0.25, 0.0], [1.0, 0.25, 0.2], [1.0, 0.0, 0.0], [1.0, 0.4, 0.5]])  # axis x through box centre
    z = radial(U, FRAME, None, **params("radial", axis="x", inner=0.1, outer=0.9, exponent=1.0))
    # centre of the (y, z) cross-section is (0.25, 0.125); the inscribed radius is 0.125
    assert z[0] == pytest.approx(0.1 + 0.8 * (0.125 / 0.125))  # on the low z face: at the radius
    centre = radial(np.array([[0.3, 0.25, 0.125]]), FRAME, None, **params("radial", axis="x", inner=0.1, outer=0.9))
    assert centre[0] == pytest.approx(0.1)
    r = np.linspace(0, 0.125, 20)
    line = np.stack([np.full_like(r, 1.0), 0.25 + r, np.full_like(r, 0.125)], 1)
    values = radial(line, FRAME, None, **params("radial", axis="x"))
    assert np.all(np.diff(values) > 0)


def test_bricks_are_weak_on_interfaces_only():
    p = params("bricks", noise_contrast=0.0)
    bl, bh, m = p["brick_length"], p["brick_height"], p["mortar"]
    rng = np.random.default_rng(0)
    brick_centre = np.array([[m + 0.5 * (bl - m), m + 0.5 * (bh - m), 0.1]])
    interface = np.array([[m, m + 0.5 * (bh - m), 0.1]])  # head-joint / brick boundary
    bed_middle = np.array([[0.5 * bl, 0.5 * m, 0.1]])  # inside the bed joint
    z = [bricks(P, FRAME, rng, **p)[0] for P in (brick_centre, interface, bed_middle)]
    assert z[0] == pytest.approx(p["brick_strength"], abs=1e-4)
    assert z[1] == pytest.approx(p["interface_strength"], abs=1e-6)
    assert z[1] < z[2] < p["mortar_strength"] + 1e-9
    # the paper's wall is strong in the mortar too: the joint's two weak layers do not merge
    assert z[2] > 0.9 * p["mortar_strength"]
    # Running bond: the next course is shifted by half a brick.
    upper = brick_centre + [0.5 * bl, bh, 0.0]
    assert bricks(upper, FRAME, rng, **p)[0] == pytest.approx(p["brick_strength"], abs=1e-4)


def test_inclusions_are_hard_cubes_in_a_soft_matrix():
    p = params("inclusions", count=1, size=0.2, noise_contrast=0.0, softness=1e-3)
    rng = np.random.default_rng(5)
    U = np.random.default_rng(6).uniform(0, FRAME.extent, (40000, 3))
    z = inclusions(U, FRAME, rng, **p)
    hard = z > 0.5 * (p["matrix_strength"] + p["inclusion_strength"])
    # The hard set is one cube of volume size^3 (in unit coordinates).
    assert hard.mean() == pytest.approx(0.2**3 / np.prod(FRAME.extent), rel=0.15)
    assert np.allclose(z[~hard].min(), p["matrix_strength"], atol=1e-3)


def test_volume_layer_reproduces_a_user_grid(tmp_path):
    grid = Grid.from_bounds([-1, -1, -1], [3, 2, 1], (9, 7, 5))
    values = grid.points() @ np.array([0.5, -1.0, 2.0])
    np.save(tmp_path / "v.npy", values.reshape(grid.shape))
    X = sample_points(500)
    z = strength_field(X, BOUNDS, [{"kind": "volume", "weight": 1.0, "path": str(tmp_path / "v.npy"),
                                    "bounds": [[-1, -1, -1], [3, 2, 1]]}], seed=0, normalize=False)
    np.testing.assert_allclose(z, X @ np.array([0.5, -1.0, 2.0]), atol=1e-12)


def test_volume_errors_name_the_file(tmp_path):
    np.save(tmp_path / "flat.npy", np.zeros((4, 4)))
    nan = np.zeros((3, 3, 3))
    nan[0, 0, 0] = np.nan
    np.save(tmp_path / "nan.npy", nan)
    (tmp_path / "junk.npy").write_bytes(b"not numpy")
    (tmp_path / "piece.obj").write_text("o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    np.save(tmp_path / "cut.npy", np.zeros((3, 3, 3)))
    (tmp_path / "cut.npy").write_bytes((tmp_path / "cut.npy").read_bytes()[:100])
    for name, match in [("missing.npy", "not found"), ("flat.npy", "expected a 3D array"),
                        ("nan.npy", "NaN"), ("junk.npy", r"not a \.npy file"), ("piece.obj", r"not a \.npy file"),
                        ("cut.npy", "cannot read")]:
        with pytest.raises(InputError, match=match) as err:
            load_volume(tmp_path / name)
        assert name in str(err.value)
    # from the config: the layer's key too
    with pytest.raises(InputError) as err:
        strength_field(sample_points(10), BOUNDS, [layer("radial"), {"kind": "volume", "path": str(tmp_path / "piece.obj")}],
                       seed=0)
    assert str(err.value).startswith(f"strength.layers[1] (volume): {tmp_path / 'piece.obj'}: not a .npy file")


def test_layers_add_with_weights():
    X = sample_points(1000)
    a = strength_field(X, BOUNDS, [layer("radial")], seed=0, normalize=False)
    b = strength_field(X, BOUNDS, [layer("bricks")], seed=0, normalize=False)
    both = strength_field(X, BOUNDS, [{**layer("radial"), "weight": 0.3}, {**layer("bricks"), "weight": 2.0}],
                          seed=0, normalize=False)
    # Layer i draws from default_rng([seed, i]); bricks is layer 1 here, so compare its deterministic part.
    bricks_as_second = strength_field(X, BOUNDS, [{**layer("radial"), "weight": 0.0}, layer("bricks")], seed=0,
                                      normalize=False)
    np.testing.assert_allclose(both, 0.3 * a + 2.0 * bricks_as_second, atol=1e-12)
    assert not np.allclose(bricks_as_second, b)  # a different layer index draws different noise

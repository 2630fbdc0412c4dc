"""The paper's five examples as built-in coarse fracture animations.

Each scene builds an exterior B, a coarse fracture surface of about the size
the paper's low-resolution simulations produced, and a deterministic coarse
animation (:mod:`fracture.coarse.scenes.animator`) in which the object breaks during
the animation. Sizes and grids follow Section 6 of the paper:

========  ==============================  =====================  =========
scene     object                          coarse fracture        grid
========  ==============================  =====================  =========
bunny     Stanford bunny dropped, shatters  ~256 triangles       50^3
branch    cylinder, incomplete cut, bends   ~60 (+ virtual)      32x32x64
wall      brick wall hit by a ball          ~204                 150x50x10
clay      twisted plastic clay bar          ~510                 32x64x64
jello     wobbling Jell-O, breaks gradually ~488                 64x64x32
========  ==============================  =====================  =========
"""

from __future__ import annotations

from pathlib import Path

import igl
import numpy as np
import triangle

from fracture.coarse.surface import CoarseFracture, make_coarse, special_edges
from fracture.errors import InputError
from fracture.io.meshes import check_triangle_mesh
from fracture.mesh.decimate import quadric_decimation
from fracture.mesh.primitives import box, cylinder
from fracture.coarse.animation import exterior_points, lattice_animation
from fracture.coarse.scenes.animator import rigid_bodies, rigid_motion, rotation
from fracture.coarse.scenes.voronoi import VoronoiFracture, seeds_inside, voronoi_fracture
from fracture.tolerances import tol

#: Coarse fracture triangles of the paper's examples (Section 6).
PAPER_TRIANGLES = {"bunny": 256, "branch": 60, "wall": 204, "clay": 510, "jello": 488}

# Attempts at drawing seeds whose cells are connected pieces.
_SEED_TRIES = 30


def bunny_mesh() -> tuple[np.ndarray, np.ndarray]:
    """The Stanford bunny shipped with pymeshlab's tests (56K triangles, closed)."""
    import pymeshlab

    path = Path(pymeshlab.__file__).parent / "tests" / "sample_meshes" / "bunny.obj"
    if not path.is_file():
        raise InputError(f"the bunny scene needs {path}, which this pymeshlab installation lacks")
    V, F = igl.read_triangle_mesh(str(path))
    return check_triangle_mesh(V, F, str(path), closed=True)


def _decimate(V, F, faces):
    return quadric_decimation(V, F, faces, preservetopology=True)


def _voronoi(BV, BF, coarse, count, spacing, edge_length, rng, what, plane=None
             ) -> tuple[VoronoiFracture, np.ndarray, list[np.ndarray]]:
    """Voronoi pieces of ``coarse`` with seeds redrawn until every piece is connected.

    Returns the pieces, the component of every triangle of B, and per piece
    its coarse corners with its exterior points (ground contacts, lattice extent).
    """
    last = None
    for _ in range(_SEED_TRIES):
        seeds = seeds_inside(*coarse, count, rng, spacing)
        if plane is not None:
            seeds[:, plane[0]] = plane[1]
        try:
            vf = voronoi_fracture(*coarse, seeds, edge_length, what)
            break
        except InputError as exc:
            last = exc
    else:
        raise InputError(f"{what}: no seed set gave connected pieces in {_SEED_TRIES} tries ({last})")
    # the coarse cut meets the coarse object; put its boundary on the detailed exterior B
    b = special_edges(vf.F, len(vf.V)).boundary_vertices
    _, _, C = igl.point_mesh_squared_distance(vf.V[b], BV, BF)
    vf.V[b] = C
    ext = vf.component_of(BV[BF].mean(axis=1))
    outside = exterior_points(BV, BF, ext, len(vf.seeds))
    return vf, ext, [np.concatenate([P, X]) for (P, _), X in zip(vf.pieces, outside)]


def _finish(name, BV, BF, ext, vf: VoronoiFracture, animation, separation) -> CoarseFracture:
    names = [f"{name}_{c:03d}" for c in range(len(vf.seeds))]
    return make_coarse(BV, BF, ext, vf.V, vf.F, vf.sides, names, animation, separation)


def bunny(rng: np.random.Generator, frames: int, separation: float) -> CoarseFracture:
    """The marble bunny dropped onto the ground; it shatters on impact."""
    BV, BF = bunny_mesh()
    vf, ext, points = _voronoi(BV, BF, _decimate(BV, BF, 700), 7, 0.15, 0.075, rng, "bunny")
    up, drop, fps = 1, 0.25, 30.0
    ground = BV[:, up].min() - drop
    impact = int(np.ceil(np.sqrt(2 * drop / 9.81) * fps))

    def carrier(t, X):  # free fall until the impact frame
        s = min(t, impact) / fps
        Y = X.copy()
        Y[:, up] -= min(0.5 * 9.81 * s * s, drop)
        return Y

    contact = BV[np.argmin(BV[:, up])]

    def kick(c):
        com = vf.pieces[c][0].mean(axis=0)
        out = com - contact
        out[up] = 0.0
        v = 0.9 * out / max(np.linalg.norm(out), tol.tiny)
        v[up] = 1.2
        return v, rng.normal(0.0, 4.0, 3)

    poses = rigid_bodies(points, frames, np.full(len(vf.seeds), impact), kick, carrier, up, ground, fps)
    anim = lattice_animation(points, rigid_motion(poses), frames)
    return _finish("bunny", BV, BF, ext, vf, anim, separation)


def wall(rng: np.random.Generator, frames: int, separation: float) -> CoarseFracture:
    """A brick wall punched by a wrecking ball: the hit pieces fly off and fall."""
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([3.0, 1.0, 0.2])
    BV, BF = box(lo, hi, (150, 50, 10))
    vf, ext, points = _voronoi(BV, BF, box(lo, hi), 12, 0.45, 0.15, rng, "wall", plane=(2, 0.1))
    hit, radius, when, up = np.array([1.5, 0.55, 0.2]), 0.8, 8, 1
    release = np.full(len(vf.seeds), frames)
    kicks = {}
    for c, s in enumerate(vf.seeds):
        d = np.linalg.norm((s - hit)[:2])
        if d < radius:
            release[c] = when
            falloff = np.exp(-(d / radius) ** 2 * 2)
            out = np.r_[(s - hit)[:2], 0.0]
            kicks[c] = (np.array([0.0, 0.0, -3.5 * falloff]) + 0.8 * out, rng.normal(0.0, 3.0, 3))
    poses = rigid_bodies(points, frames, release, lambda c: kicks[c], None, up, 0.0)
    anim = lattice_animation(points, rigid_motion(poses), frames)
    return _finish("wall", BV, BF, ext, vf, anim, separation)


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def clay(rng: np.random.Generator, frames: int, separation: float) -> CoarseFracture:
    """A bar of plastic clay twisted about its long axis; it tears and keeps its shape."""
    lo, hi = np.array([-0.5, -1.0, -1.0]), np.array([0.5, 1.0, 1.0])
    BV, BF = box(lo, hi, (32, 64, 64))
    vf, ext, points = _voronoi(BV, BF, box(lo, hi), 14, 0.4, 0.27, rng, "clay")
    total = np.radians(150.0)
    breaks = max(1, int(0.35 * frames))

    def angle(z, t):  # twist grows along z and in time
        return total * _smoothstep(t / (frames - 1)) * (z - lo[2]) / (hi[2] - lo[2])

    def twist(X, t):
        a = angle(X[:, 2], t)
        c, s = np.cos(a), np.sin(a)
        return np.stack([c * X[:, 0] - s * X[:, 1], s * X[:, 0] + c * X[:, 1], X[:, 2]], 1)

    com = np.array([PV.mean(axis=0) for PV, _ in vf.pieces])

    def motion(c, t, X):
        if t <= breaks:
            return twist(X, t)
        # torn off: keeps the shape it had, turns with the twist at its height and drifts out
        Y = twist(X, breaks)
        R = rotation([0, 0, 1], angle(com[c, 2], t) - angle(com[c, 2], breaks))
        out = np.r_[com[c, :2], 0.0]
        return Y @ R.T + 0.15 * (t - breaks) / frames * out
    anim = lattice_animation(points, motion, frames, n=7, shared=True)
    return _finish("clay", BV, BF, ext, vf, anim, separation)


def jello(rng: np.random.Generator, frames: int, separation: float) -> CoarseFracture:
    """A block of Jell-O on a plate: a jolt sets it wobbling, pieces slump off one by one."""
    lo, hi = np.array([-1.0, -1.0, 0.0]), np.array([1.0, 1.0, 1.0])
    BV, BF = box(lo, hi, (64, 64, 32))
    vf, ext, points = _voronoi(BV, BF, box(lo, hi), 14, 0.4, 0.28, rng, "jello")
    com = np.array([PV.mean(axis=0) for PV, _ in vf.pieces])
    radial = np.linalg.norm(com[:, :2], axis=1)
    order = np.argsort(-radial)  # outer pieces let go first
    release = np.empty(len(com), np.int64)
    release[order] = np.round(np.linspace(0.3, 0.7, len(com)) * frames).astype(np.int64)
    fps, omega, damping = 30.0, 2 * np.pi * 2.0, 2.5

    def wobble(X, t):
        s = t / fps
        amp = np.exp(-damping * s) * np.sin(omega * s)
        h = X[:, 2] / hi[2]
        Y = X.copy()
        Y[:, 0] += 0.25 * amp * h * h
        Y[:, 1] += 0.08 * amp * h * h
        Y[:, 2] *= 1.0 - 0.08 * amp
        return Y

    def motion(c, t, X):
        Y = wobble(X, t)
        if t > release[c]:
            k = 1.0 - np.exp(-(t - release[c]) / 6.0)
            Y[:, :2] += 0.3 * k * com[c, :2]
            Y[:, 2] *= 1.0 - 0.15 * k
        return Y
    anim = lattice_animation(points, motion, frames, n=7, shared=True)
    return _finish("jello", BV, BF, ext, vf, anim, separation)


def half_disk(radius: float, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Triangulated half disk ``y >= 0`` in the plane ``z = 0``."""
    k = max(4, int(np.ceil(np.pi * radius / h)))
    th = np.linspace(0.0, np.pi, k + 1)
    arc = np.stack([radius * np.cos(th), radius * np.sin(th)], 1)
    m = max(2, int(np.ceil(2 * radius / h)))
    diameter = np.stack([np.linspace(-radius, radius, m + 1)[1:-1], np.zeros(m - 1)], 1)
    P = np.concatenate([arc, diameter])
    n = len(P)
    segs = np.stack([np.arange(n), (np.arange(n) + 1) % n], 1)
    out = triangle.triangulate({"vertices": P, "segments": segs}, f"pq30Ya{np.sqrt(3) / 4 * h * h:.12g}Q")
    V = np.column_stack([out["vertices"], np.zeros(len(out["vertices"]))])
    F = out["triangles"].astype(np.int64)
    nrm = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])[:, 2]
    F[nrm < 0] = F[nrm < 0][:, ::-1]  # normal +z: from the lower part into the upper
    return V, F


_BRANCH_CUT_TILT = 35.0  # degrees between the branch's cut and its cross-section


def branch(rng: np.random.Generator, frames: int, separation: float) -> CoarseFracture:
    """A tree branch with an oblique cut through half its section: it bends, the cut opens, the rest holds.

    The cut is incomplete; virtual fracture extends it across the section so
    the branch has two components, and the extension never opens.
    """
    from fracture.coarse.components import label_components
    from fracture.coarse.virtual import extend_cuts

    radius, length = 0.5, 2.0
    BV, BF = cylinder(radius, length, segments=96, rings=129)
    BV[:, 2] -= length / 2
    V, F = half_disk(radius, 0.16)
    # the cut runs obliquely across the grain, as a bent branch breaks: z = y tan(35 degrees) (its rim stays
    # on the bark); a cut square to the axis would feel only the grain's slow change along the axis
    V[:, 2] = V[:, 1] * np.tan(np.radians(_BRANCH_CUT_TILT))
    arc = np.isclose(np.linalg.norm(V[:, :2], axis=1), radius)
    _, _, C = igl.point_mesh_squared_distance(V[arc], BV, BF)
    V[arc] = C
    V, F, virtual = extend_cuts(V, F, BV, BF)
    sides, ext, n = label_components(BV, BF, V, F, what="branch")
    points = exterior_points(BV, BF, ext, n)
    com = np.array([P.mean(axis=0) for P in points])
    top = int(np.argmax(com[:, 2]))
    start = max(1, int(0.25 * frames))
    bend = np.radians(rng.uniform(22.0, 28.0))

    def motion(c, t, X):
        if c != top or t <= start:
            return X
        R = rotation([1.0, 0.0, 0.0], bend * _smoothstep((t - start) / (frames - 1 - start)))
        return X @ R.T  # about the crack front, the x axis through the origin
    anim = lattice_animation(points, motion, frames)
    names = [f"branch_{c:03d}" for c in range(n)]
    return make_coarse(BV, BF, ext, V, F, sides, names, anim, separation, virtual=virtual)


SCENES = {"bunny": bunny, "branch": branch, "wall": wall, "clay": clay, "jello": jello}


def build_scene(name: str, seed: int = 0, frames: int = 40, separation: float = 1e-3) -> CoarseFracture:
    """Build a built-in scene (deterministic for a given seed)."""
    if name not in SCENES:
        raise InputError(f"unknown scene {name!r}; expected one of {', '.join(SCENES)}")
    if frames < 4:
        raise InputError(f"scene {name!r}: needs at least 4 frames, got {frames}")
    return SCENES[name](np.random.default_rng([seed, 0x5CE4E]), frames, separation)

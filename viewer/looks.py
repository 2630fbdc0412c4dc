"""The look of the three panels, shared by the window and the headless renderer.

Each ``show_*`` function fills an ``open3d.visualization.rendering.Open3DScene``
(a SceneWidget's or an OffscreenRenderer's) from a :class:`~viewer.data.RunData`
with what stays while a slider moves; the ``set_*`` functions replace only
what the slider changes (the slice, the iteration's surface). A figure
rendered with ``fracref render`` therefore looks like the window.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import open3d as o3d
from open3d.visualization import rendering

from fields.colormap import colormap, srgb_to_linear
from fields.slices import axis_slice
from fracture.mesh.topology import face_frames, unique_edges
from viewer.annotate import finish
from viewer.data import RunData, Surface
from viewer.tolerances import view_tol
from viewer.view import SURFACE_CMAPS, CameraPose, View

# White: the renderer's colour grading maps 1.0 to 248, so the background is given a little above it.
BACKGROUND = (1.07, 1.07, 1.07, 1.0)
# The ground under the pieces, a light warm grey that takes their shadows.
GROUND_COLOR = (0.93, 0.92, 0.90, 1.0)
# Fracture faces: the piece's colour mixed this much toward a stone colour (the inside of the material).
INTERIOR_MIX, INTERIOR_COLOR = 0.6, np.array([0.93, 0.90, 0.84])
# Piece colours: the Okabe-Ito palette (distinguishable with colour-blindness), then a hue walk.
PIECE_COLORS = np.array([[0.90, 0.62, 0.00], [0.34, 0.71, 0.91], [0.00, 0.62, 0.45], [0.94, 0.89, 0.26],
                         [0.00, 0.45, 0.70], [0.84, 0.37, 0.00], [0.80, 0.47, 0.65], [0.60, 0.60, 0.60]])
FIELD_CMAPS = {"psi": "coolwarm", "zeta": "viridis", "xi": "magma"}


# -- geometry ---------------------------------------------------------------------------------


def linear(rgb) -> np.ndarray:
    """sRGB colours (as colour maps and colour bars give them) in linear light, which is what
    Filament takes for vertex and base colours: it encodes its output to sRGB, so a colour
    given as is would be encoded twice and come out pale."""
    return srgb_to_linear(rgb)


def triangle_mesh(V: np.ndarray, F: np.ndarray, colors: np.ndarray | None = None,
                  flat: bool = False) -> o3d.geometry.TriangleMesh:
    """An Open3D mesh; ``flat`` shades each triangle with its own normal (sharp creases, e.g. a box's edges)."""
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(V, np.float64)),
                                  o3d.utility.Vector3iVector(np.asarray(F, np.int32)))
    if colors is not None:  # sRGB in, linear to the renderer
        m.vertex_colors = o3d.utility.Vector3dVector(linear(colors))
    if flat:  # Open3D draws a mesh without vertex normals with its triangle normals
        m.compute_triangle_normals()
    else:
        m.compute_vertex_normals()
    return m


def wireframe(V: np.ndarray, E: np.ndarray) -> o3d.geometry.LineSet:
    """Line set of the edges ``E (k, 2)`` over ``V`` (e.g. ``topology.unique_edges(F)[0]``)."""
    return o3d.geometry.LineSet(o3d.utility.Vector3dVector(np.asarray(V, np.float64)),
                                o3d.utility.Vector2iVector(E.astype(np.int32)))


# The slice is drawn as a mesh with a colour per vertex; the renderer blends vertex colours in
# linear light, not along the colour map, so the grid's cells are subdivided (bilinear values)
# until a cell is a few pixels, up to this many vertices.
SLICE_VERTICES = 250_000


def slice_plane(run: RunData, view: View, mask: bool = True) -> tuple[o3d.geometry.TriangleMesh, tuple[float, float]]:
    """The field slice as a flat coloured mesh in material space, and its value range.

    The grid's values are interpolated bilinearly onto a finer lattice (the colours follow the
    colour map within a cell); with ``mask``, only the triangles inside the object are kept
    (B's winding number at the slice's grid nodes, interpolated the same way).
    """
    from scipy.ndimage import zoom

    values = run.field(view.field, view.level)
    plane, info = axis_slice(run.grid, values, view.axis, view.offset)
    vmin, vmax = run.field_range(view.field, view.level)
    n0 = plane.shape
    u = np.linspace(*info["extent"][0], n0[0])
    v = np.linspace(*info["extent"][1], n0[1])

    def lattice(u, v):
        U, W = np.meshgrid(u, v, indexing="ij")
        P = np.zeros((U.size, 3))
        P[:, info["u"]], P[:, info["v"]], P[:, info["axis"]] = U.ravel(), W.ravel(), info["position"]
        return P

    inside = run.solid.inside(lattice(u, v)).reshape(n0).astype(np.float64) if mask else None
    factor = int(np.clip(np.sqrt(SLICE_VERTICES / plane.size), 1, 8))
    if factor > 1:
        plane = zoom(plane.astype(np.float64), factor, order=1, grid_mode=False)
        inside = zoom(inside, factor, order=1, grid_mode=False) if mask else None
    nu, nv = plane.shape
    P = lattice(np.linspace(*info["extent"][0], nu), np.linspace(*info["extent"][1], nv))
    idx = np.arange(nu * nv).reshape(nu, nv)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    if mask:
        keep = inside.ravel()[F].mean(axis=1) >= 0.5
        F = F[keep] if keep.any() else F
    return triangle_mesh(P, F, colormap(plane.ravel(), FIELD_CMAPS[view.field], vmin, vmax)), (vmin, vmax)


# -- materials ----------------------------------------------------------------------------------


def lit(color=(0.8, 0.8, 0.8, 1.0)) -> rendering.MaterialRecord:
    m = rendering.MaterialRecord()
    m.shader = "defaultLit"
    m.base_color = [*linear(color[:3]), color[3]]
    m.base_roughness = 0.7
    return m


def unlit() -> rendering.MaterialRecord:
    m = rendering.MaterialRecord()
    m.shader = "defaultUnlit"
    return m


def glass(alpha: float = 0.18) -> rendering.MaterialRecord:
    m = rendering.MaterialRecord()
    m.shader = "defaultLitTransparency"
    m.base_color = [*linear([0.55, 0.6, 0.7]), alpha]
    m.base_roughness = 0.5
    return m


def lines(color=(0.1, 0.1, 0.1, 1.0), width: float = 1.5) -> rendering.MaterialRecord:
    m = rendering.MaterialRecord()
    m.shader = "unlitLine"
    m.base_color = [*linear(color[:3]), color[3]]
    m.line_width = width
    return m


# -- scenes -------------------------------------------------------------------------------------


def prepare(scene: rendering.Open3DScene, sun=(0.3, -0.5, -0.8)) -> None:
    """White background, soft light from ``sun`` (the direction the light travels) with the shadows
    it casts, no axes."""
    scene.clear_geometry()
    scene.set_background(list(BACKGROUND))
    scene.show_axes(False)
    scene.set_lighting(rendering.Open3DScene.LightingProfile.SOFT_SHADOWS, np.asarray(sun, np.float32))
    scene.view.set_shadowing(True, rendering.View.ShadowType.PCF)
    scene.view.set_color_grading(rendering.ColorGrading(rendering.ColorGrading.Quality.HIGH,
                                                        rendering.ColorGrading.ToneMapping.LINEAR))


def capture(scene: rendering.Open3DScene, shot, k: int = 1, transparent: bool = False) -> np.ndarray:
    """A figure's picture of ``scene`` from ``shot()`` (the scene rendered, RGB), ``k`` times smaller
    (supersampled) and, when ``transparent``, with alpha from a second shot on black
    (:func:`viewer.annotate.finish`); the background is put back."""
    on_white, on_black = shot(), None
    if transparent:
        scene.set_background([0.0, 0.0, 0.0, 1.0])
        try:
            on_black = shot()
        finally:
            scene.set_background(list(BACKGROUND))
    return finish(on_white, on_black, k)


def _replace(scene: rendering.Open3DScene, name: str, geometry, material) -> None:
    if scene.has_geometry(name):
        scene.remove_geometry(name)
    scene.add_geometry(name, geometry, material)


@lru_cache(maxsize=1)  # the run on screen; an old run is let go
def exterior_mesh(run: RunData) -> o3d.geometry.TriangleMesh:
    """B as an Open3D mesh, built once per run (every panel shows it)."""
    return triangle_mesh(run.exterior.V, run.exterior.F, flat=True)


def show_material(scene: rendering.Open3DScene, run: RunData) -> None:
    """Panel 1 without its slice: the coarse (wireframe) and refined fracture surfaces and a see-through exterior."""
    prepare(scene)
    cf = run.coarse_fracture
    scene.add_geometry("coarse", wireframe(cf.V, unique_edges(cf.F)[0]), lines((0.1, 0.1, 0.1, 1.0), 2.0))
    if run.refined_fracture is not None:
        rf = run.refined_fracture
        scene.add_geometry("refined", triangle_mesh(rf.V, rf.F), lit((0.85, 0.85, 0.82, 1.0)))
    scene.add_geometry("exterior", exterior_mesh(run), glass())


def set_slice(scene: rendering.Open3DScene, run: RunData, view: View) -> tuple[float, float]:
    """Panel 1's field slice (replacing the previous one); returns its colour range."""
    plane, rng = slice_plane(run, view)
    _replace(scene, "slice", plane, unlit())
    return rng


def show_context(scene: rendering.Open3DScene, run: RunData) -> None:
    """Panel 2 without its surface: a faint exterior."""
    prepare(scene)
    scene.add_geometry("exterior", exterior_mesh(run), glass(0.12))


def set_surface(scene: rendering.Open3DScene, surface: Surface, color_by: str, rng: tuple[float, float],
                cmap: str | None = None) -> None:
    """Panel 2's fracture surface coloured by its ``psi`` or ``speed`` scalars (or another, with its ``cmap``),
    replacing the previous one."""
    colors = colormap(surface.scalars[color_by], cmap or SURFACE_CMAPS[color_by], *rng)
    _replace(scene, "surface", triangle_mesh(surface.V, surface.F, colors), lit((1, 1, 1, 1)))


def slice_title(view: View) -> str:
    level = f" (level {view.level})" if view.field == "psi" and view.level else ""
    return f"{view.field}{level}, {view.axis} = {view.offset:.2f}"


def iteration_caption(run: RunData, k: int) -> str:
    """``iteration k / n (what it is), m triangles, E = e``: iteration 0 is the coarse surface, an iteration
    of stage -1 the global search's surface (coarse -> searched -> polished)."""
    e = run.energy[k] if 0 <= k < len(run.energy) else None
    stages = run.stages
    searched = -1 in stages
    what = ("coarse" if k == 0 else "searched" if 0 <= k < len(stages) and stages[k] == -1
            else "polished" if searched else "")
    return (f"iteration {k} / {len(run.iterations) - 1}" + (f" ({what})" if what else "")
            + f", {len(run.iterations[k]['faces']):,} triangles" + (f", E = {e:.4g}" if e is not None else ""))


def show_stage(scene: rendering.Open3DScene, run: RunData) -> None:
    """Panel 3 without its pieces: a ground under the box the pieces move in, lit from above so
    that the pieces cast shadows on it."""
    up = "xyz".index(run.up_axis)
    sun = -np.eye(3)[up] + 0.35 * np.eye(3)[(up + 1) % 3] + 0.2 * np.eye(3)[(up + 2) % 3]
    prepare(scene, sun)
    lo, hi = animation_box(run)
    scene.add_geometry("ground", ground_quad(lo, hi, up), lit(GROUND_COLOR))


def ground_quad(lo, hi, up: int, scale: float = 30.0) -> o3d.geometry.TriangleMesh:
    """A square under the box ``lo, hi`` (just below its lowest point along axis ``up``), ``scale``
    times the box's widest side, facing up."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    a, b = (up + 1) % 3, (up + 2) % 3
    mid, half = 0.5 * (lo + hi), 0.5 * scale * max(hi[a] - lo[a], hi[b] - lo[b], view_tol.extent)
    V = np.zeros((4, 3))
    V[:, a] = mid[a] + half * np.array([-1, 1, 1, -1])
    V[:, b] = mid[b] + half * np.array([-1, -1, 1, 1])
    V[:, up] = ground_height(lo, hi, up)
    return triangle_mesh(V, np.array([[0, 1, 2], [0, 2, 3]]), flat=True)


def ground_height(lo, hi, up: int) -> float:
    """Where the ground under the box ``lo, hi`` lies along axis ``up``: just below the box."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    return float(lo[up] - view_tol.floor_gap * np.linalg.norm(hi - lo))


def interior_color(c: int) -> tuple[float, float, float]:
    """The fracture faces' colour of piece ``c``: its colour toward stone."""
    return tuple((1 - INTERIOR_MIX) * np.asarray(piece_color(c)) + INTERIOR_MIX * INTERIOR_COLOR)


def piece_meshes(p: Surface):
    """A piece's outside and its fracture faces as two meshes (each drawn in its own colour)."""
    ext = p.scalars.get("exterior", np.ones(len(p.F), bool))
    return triangle_mesh(p.V, p.F[ext], flat=True), triangle_mesh(p.V, p.F[~ext], flat=True)


def show_pieces(scene: rendering.Open3DScene, pieces: list[Surface], prefix: str = "piece") -> None:
    """The pieces in their colours, fracture faces lighter (replacing any drawn under the same names)."""
    for c, p in enumerate(pieces):
        outside, inside = piece_meshes(p)
        _replace(scene, f"{prefix}_{c}", outside, lit((*piece_color(c), 1.0)))
        if len(inside.triangles):
            _replace(scene, f"{prefix}_{c}_fracture", inside, lit((*interior_color(c), 1.0)))
        elif scene.has_geometry(f"{prefix}_{c}_fracture"):
            scene.remove_geometry(f"{prefix}_{c}_fracture")


def pieces_caption(name: str, pieces: list[Surface], t: int) -> str:
    """``coarse: 8 pieces, 50,848 triangles, frame 40`` (a half of the coarse-vs-refined figure)."""
    return f"{name}: {len(pieces)} pieces, {sum(len(p.F) for p in pieces):,} triangles, frame {t + 1}"


def set_frame(scene: rendering.Open3DScene, run: RunData, view: View) -> None:
    """Panel 3 (after :func:`show_stage`): the high-resolution pieces at frame ``view.frame``, replacing
    the previous frame's, and the coarse pieces see-through while ``view.overlay_coarse`` is on."""
    show_pieces(scene, run.pieces_at(view.frame))
    # the coarse pieces see-through over the detailed ones (their edges would hide them: B is fine)
    coarse = run.coarse_pieces(view.frame) if view.overlay_coarse else []
    for c, p in enumerate(coarse):
        _replace(scene, f"coarse_{c}", triangle_mesh(p.V, p.F, flat=True), glass(0.25))
    for c in range(len(coarse), len(run.coarse_parts)):
        if scene.has_geometry(f"coarse_{c}"):
            scene.remove_geometry(f"coarse_{c}")


def set_cutaway(scene: rendering.Open3DScene, run: RunData, view: View) -> None:
    """Panel 1's cutaway: with ``view.cutaway``, the high-resolution pieces (as assembled) on the
    low side of the slice plane, so the slice caps them; without it, none."""
    names = [n for c in range(len(run.piece_faces) if run.has_animation else 0)
             for n in (f"cut_{c}", f"cut_{c}_fracture")]
    for n in names:
        if scene.has_geometry(n):
            scene.remove_geometry(n)
    if not (view.cutaway and run.has_animation):
        return
    a = "xyz".index(view.axis)
    lo, hi = run.grid.lo, run.grid.hi
    point = np.zeros(3)
    point[a] = lo[a] + view.offset * (hi[a] - lo[a])
    for c, p in enumerate(run.pieces_rest()):
        for name, mesh, color in zip((f"cut_{c}", f"cut_{c}_fracture"), piece_meshes(p),
                                     (piece_color(c), interior_color(c))):
            if len(mesh.triangles) == 0:
                continue
            cut = o3d.t.geometry.TriangleMesh.from_legacy(mesh).clip_plane(point, -np.eye(3)[a]).to_legacy()
            if len(cut.triangles):
                cut.compute_triangle_normals()
                scene.add_geometry(name, cut, lit((*color, 1.0)))


def piece_color(c: int) -> tuple[float, float, float]:
    if c < len(PIECE_COLORS):
        return tuple(PIECE_COLORS[c])
    h = (0.61803398875 * c) % 1.0  # golden-ratio hue walk
    import colorsys

    return colorsys.hsv_to_rgb(h, 0.55, 0.9)


# -- cameras ------------------------------------------------------------------------------------


def frame_points(P: np.ndarray, aspect: float = 16 / 9, look: np.ndarray | None = None,
                 up: np.ndarray | None = None, fov: float = 35.0, margin: float = 1.1) -> CameraPose:
    """A three-quarter view that fits points ``P`` (e.g. a box's corners) into the picture.

    ``look`` is the main viewing direction (default: the points' thinnest
    principal axis, so a slab is seen face-on) and ``up`` the screen's up
    (default: the middle principal axis). The camera turns a little off
    ``look`` (right and down), and its distance is the smallest at which
    every point is inside both fields of view narrowed by ``margin``; the points are centred in the picture.
    """
    P = np.asarray(P, np.float64).reshape(-1, 3)
    axes = np.linalg.svd(P - P.mean(axis=0), full_matrices=False)[2] if len(P) >= 3 else np.eye(3)
    look = axes[-1] if look is None else np.asarray(look, np.float64)
    look = look / np.linalg.norm(look)
    up = axes[1] if up is None else np.asarray(up, np.float64)
    up = up - (up @ look) * look
    if np.linalg.norm(up) < view_tol.across:
        up = np.eye(3)[np.argmin(np.abs(look))]
        up = up - (up @ look) * look
    up /= np.linalg.norm(up)
    right = np.cross(up, look)
    direction = look + 0.45 * right + 0.3 * up
    direction /= np.linalg.norm(direction)
    cam_up = up - (up @ direction) * direction
    cam_up /= np.linalg.norm(cam_up)
    cam_right = np.cross(direction, cam_up)
    tan_v = np.tan(np.radians(fov) / 2) / margin  # the points fill the picture less ``margin``
    tan_h = tan_v * aspect
    # The nearest eye (coordinates ex, ey, ez along cam_right, cam_up, direction) with every point
    # inside the four planes of the view: |x - ex| <= tan * (ez - z) for each point, and the points
    # centred between the opposite planes. Each pair of planes gives ez and the centring offset.
    x, y, z = P @ cam_right, P @ cam_up, P @ direction
    a, b = np.max(tan_h * z + x), np.max(tan_h * z - x)
    c, d = np.max(tan_v * z + y), np.max(tan_v * z - y)
    ex, ey = 0.5 * (a - b), 0.5 * (c - d)
    ez = max(0.5 * (a + b) / tan_h, 0.5 * (c + d) / tan_v)
    zc = 0.5 * (z.min() + z.max())  # the point looked at: the points' middle depth
    ez = max(ez, zc + view_tol.depth)
    center = ex * cam_right + ey * cam_up + zc * direction
    return CameraPose(center, ex * cam_right + ey * cam_up + ez * direction, cam_up, fov)


def box_corners(lo, hi) -> np.ndarray:
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    return np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])


def frame_box(lo, hi, aspect: float = 16 / 9, look=None, up=None) -> CameraPose:
    """:func:`frame_points` of a box, looking along its thinnest side, up along its middle one."""
    ext = np.asarray(hi, np.float64) - np.asarray(lo, np.float64)
    order = np.argsort(ext)
    look = np.eye(3)[order[0]] if look is None else look
    up = np.eye(3)[order[1]] if up is None else up
    return frame_points(box_corners(lo, hi), aspect, look, up)


def dominant_normal(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """The direction most triangles of a surface face (sign-free: the top eigenvector of sum of area n n^T)."""
    area, n = face_frames(V, F)
    return np.linalg.eigh((n * area[:, None]).T @ n)[1][:, -1]


def spread(P: np.ndarray, n: int = 4000) -> np.ndarray:
    """At most ``n`` of the points ``P``, evenly through the array (enough to frame a camera)."""
    P = np.asarray(P, np.float64).reshape(-1, 3)
    return P if len(P) <= n else P[np.linspace(0, len(P) - 1, n).astype(np.int64)]


def slice_pose(run: RunData, view: View, aspect: float) -> CameraPose:
    """Panel 1's camera: facing the slice plane, fitted to the object."""
    lo, hi = scene_box(run)
    a = "xyz".index(view.axis)
    others = [b for b in range(3) if b != a]
    up = others[int(np.argmin(hi[others] - lo[others]))]
    return frame_points(spread(run.exterior.V), aspect, np.eye(3)[a], np.eye(3)[up])


def iteration_pose(run: RunData, aspect: float) -> CameraPose:
    """Panel 2's camera: facing the fracture surface (its dominant normal), fitted to it over all iterations."""
    last = run.iterations[-1]
    look = dominant_normal(last["positions"].astype(np.float64), last["faces"])
    lo, hi = scene_box(run)
    up_axis = np.eye(3)[int(np.argsort(hi - lo)[1])]
    return frame_points(iteration_points(run), aspect, look, up_axis)


def iteration_points(run: RunData) -> np.ndarray:
    """The fracture surface's vertices over all iterations (a spread of them)."""
    return spread(np.concatenate([spread(it["positions"], 2000) for it in run.iterations]))


def iteration_box(run: RunData) -> tuple[np.ndarray, np.ndarray]:
    """The box holding the fracture surface at every iteration."""
    return run.iteration_bounds


def scene_box(run: RunData) -> tuple[np.ndarray, np.ndarray]:
    V = run.exterior.V
    return V.min(axis=0), V.max(axis=0)


def animation_points(run: RunData) -> np.ndarray:
    """Points of every coarse piece in every frame (:attr:`RunData.motion_points`, with a spread of
    the object at rest): the camera frames the whole motion and does not chase the pieces."""
    return np.concatenate([spread(run.exterior.V), run.motion_points])


def animation_box(run: RunData) -> tuple[np.ndarray, np.ndarray]:
    """The box holding every piece in every frame."""
    P = animation_points(run)
    return P.min(axis=0), P.max(axis=0)


def animation_pose(run: RunData, aspect: float, points: np.ndarray | None = None) -> CameraPose:
    """Panel 3's camera: from the side and a little above, the run's up axis up (the drop is seen),
    facing the wider side of the box the pieces move in; fitted to ``points`` (default: the pieces
    over all frames)."""
    P = animation_points(run)
    lo, hi = P.min(axis=0), P.max(axis=0)
    up = "xyz".index(run.up_axis)
    flat = [a for a in range(3) if a != up]
    look = flat[int(np.argmin((hi - lo)[flat]))]
    return frame_points(P if points is None else points, aspect, np.eye(3)[look], np.eye(3)[up])


def turntable_poses(run: RunData, pieces: list[Surface], aspect: float, n: int) -> list[CameraPose]:
    """``n`` cameras on one turn about the up axis through the pieces' middle, each fitted
    to the pieces, a little above them."""
    up = np.eye(3)["xyz".index(run.up_axis)]
    P = spread(np.concatenate([p.V for p in pieces]), 20000)
    a, b = np.eye(3)[("xyz".index(run.up_axis) + 1) % 3], np.eye(3)[("xyz".index(run.up_axis) + 2) % 3]
    poses = []
    for k in range(n):
        t = 2 * np.pi * k / n
        poses.append(frame_points(P, aspect, np.cos(t) * a + np.sin(t) * b, up))
    d = max(np.linalg.norm(p.eye - p.center) for p in poses)  # one distance: the object does not breathe
    return [CameraPose(p.center, p.center + d * (p.eye - p.center) / np.linalg.norm(p.eye - p.center), p.up, p.fov)
            for p in poses]


def apply_camera(camera: rendering.Camera, pose: CameraPose, width: int, height: int,
                 picture: tuple[int, int] | None = None) -> None:
    """Set ``camera`` to ``pose`` for an image of ``width x height``. With ``picture = (w, h)``, the
    pose's field of view spans only the image's upper-left ``w x h`` (a figure's picture; its
    colour bar and caption strips cover the rest)."""
    d = float(np.linalg.norm(pose.eye - pose.center))
    set_frustum(camera, pose.fov, width, height, picture, 0.01 * d, 100.0 * d)
    camera.look_at(pose.center, pose.eye, pose.up)


def set_frustum(camera: rendering.Camera, fov: float, width: int, height: int, picture: tuple[int, int] | None,
                near: float, far: float) -> None:
    """A perspective projection of vertical field of view ``fov`` over the ``picture`` part (upper left)
    of a ``width x height`` image."""
    pw, ph = picture if picture is not None else (width, height)
    px = 2.0 * near * np.tan(np.radians(fov) / 2) / ph  # one pixel at the near plane
    camera.set_projection(rendering.Camera.Projection.Perspective, -0.5 * pw * px, (width - 0.5 * pw) * px,
                          -(height - 0.5 * ph) * px, 0.5 * ph * px, near, far)

"""What the viewer shows, read from a run directory (``fracref run``'s output).

A run directory holds ``manifest.json`` (written last: a directory with one
is a complete run), the resolved ``config.yaml`` and each stage's files.
:class:`RunData` reads what is there; a run stopped early (``--until``)
has no iterations or animation, and the views that need them say so.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from fields.grid import Grid
from fracture.errors import InputError
from fracture.io import layout
from fracture.pipeline.sweep import Point

FIELDS = ("psi", "zeta", "xi")


@dataclass
class Surface:
    """A triangle mesh with optional per-vertex scalars."""

    V: np.ndarray
    F: np.ndarray
    scalars: dict = field(default_factory=dict)


@dataclass(frozen=True)
class SweepPoint:
    """A finished point of a sweep (``fracref sweep``): its directory's name, its values and its run."""

    name: str
    label: str
    dir: Path


def read_sweep(sweep_dir: str | Path) -> list[SweepPoint]:
    """The finished points of a sweep directory, in the sweep's order."""
    sweep_dir = Path(sweep_dir)
    try:
        state = json.loads((sweep_dir / "sweep.json").read_text(encoding="utf-8"))
        listed = state["points"]
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as exc:
        raise InputError(f"{sweep_dir / 'sweep.json'}: not a sweep's record ({exc}); expected the file "
                         "`fracref sweep` writes") from None
    points = [SweepPoint(name, Point(tuple(p.get("values", {}).items())).label, sweep_dir / name)
              for name, p in listed.items() if (sweep_dir / name / layout.MANIFEST).is_file()]
    if not points:
        raise InputError(f"{sweep_dir}: no point of this sweep has finished yet (expected run directories with "
                         "manifest.json)")
    return points


class RunData:
    """Lazy access to one run directory's outputs (material space unless said otherwise)."""

    def __init__(self, run_dir: str | Path):
        self.dir = Path(run_dir)
        manifest = self.dir / layout.MANIFEST
        if not self.dir.is_dir():
            raise InputError(f"{self.dir}: no such run directory (make one with `fracref run CONFIG --out DIR`)")
        layout.not_a_sweep(self.dir, "name")
        if not manifest.is_file():
            raise InputError(f"{self.dir}: not a complete run directory (no manifest.json; "
                             f"a run writes it last, so the run failed or is still going)")
        try:
            self.manifest = layout.manifest_object(json.loads(manifest.read_text(encoding="utf-8")), manifest)
        except json.JSONDecodeError as exc:
            raise InputError(f"{manifest}: not valid JSON ({exc})") from None
        self._memo: dict = {}

    def _path(self, rel: str) -> Path:
        return self.dir / rel

    def has(self, rel: str) -> bool:
        return self._path(rel).is_file()

    def _require(self, rel: str, what: str) -> Path:
        p = self._path(rel)
        if not p.is_file():
            stages = ", ".join(self.manifest.get("stages", {})) or "none"
            raise InputError(f"{self.dir}: {what} needs {rel}, which this run does not have "
                             f"(stages run: {stages})")
        return p

    def _read(self, rel: str, what: str, load):
        """``load(path)`` of the run's file ``rel``, which ``what`` needs: a file that is missing or cannot be
        read (a run copied in part, a disk that filled) is said in one line."""
        path = self._require(rel, what)
        with layout.reading(self.dir, rel, f"cannot show {what}"):
            return load(path)

    @cached_property
    def config(self) -> dict:
        import yaml

        return self._read(layout.CONFIG, "the config", lambda p: yaml.safe_load(p.read_text(encoding="utf-8")))

    @property
    def up_axis(self) -> str:
        """The axis gravity pulls against (``stats.coarse.up_axis``; z for runs that do not say)."""
        return str(self.manifest.get("stats", {}).get("coarse", {}).get("up_axis", "z"))

    @property
    def seconds_per_frame(self) -> float:
        """How long one frame of the run's animation lasts: as its USD file plays it (the input's frame step over
        the frame rate, :func:`fracture.io.usd.run_usd_timing`)."""
        from fracture.io.usd import run_usd_timing

        timing = run_usd_timing(self.config, self.manifest)
        return timing["frame_step"] / timing["fps"]

    @property
    def name(self) -> str:
        return str(self.manifest.get("name", self.dir.name))

    # -- fields ---------------------------------------------------------------------------

    @property
    def has_fields(self) -> bool:
        return self.has(layout.GRID) and self.has(layout.PYRAMID)

    @cached_property
    def grid(self) -> Grid:
        return self._read(layout.GRID, "the fields", lambda p: Grid.from_dict(json.loads(p.read_text())))

    @cached_property
    def _pyramid(self) -> np.ndarray:
        return self._read(layout.PYRAMID, "the strength pyramid", lambda p: np.load(p, mmap_mode="r"))

    @property
    def pyramid_levels(self) -> int:
        return int(self._pyramid.shape[0]) if self.has(layout.PYRAMID) else 1

    def field(self, name: str, level: int = 0) -> np.ndarray:
        """Field ``name`` (zeta, xi or psi) on the grid; psi at pyramid ``level`` (0 = finest).

        Read once per field and level (a slider moves through one field many times).
        """
        if name not in FIELDS:
            raise InputError(f"field must be one of {', '.join(FIELDS)}, got {name!r}")
        level = level if name == "psi" else 0
        if (name, level) not in self._memo:
            if level:
                if not 0 <= level < self.pyramid_levels:
                    raise InputError(f"pyramid level must be in 0..{self.pyramid_levels - 1}, got {level}")
                values = np.asarray(self._pyramid[level])
            else:
                values = self._read(layout.field(name), f"the {name} field", np.load)
            if values.shape != tuple(self.grid.shape):  # a file of another run, or written in part
                raise InputError(f"{self.dir}: {layout.field(name) if not level else layout.PYRAMID} holds values of "
                                 f"shape {values.shape}, expected the grid's {tuple(self.grid.shape)}; run the config "
                                 "again to write it whole")
            self._memo[name, level] = values
        return self._memo[name, level]

    def surface_range(self, color_by: str) -> tuple[float, float]:
        """Colour range of psi or speed over all iterations (so colours compare across iterations), computed once."""
        key = ("surface range", color_by)
        if key not in self._memo:
            v = np.concatenate([it[color_by] for it in self.iterations])
            lo, hi = np.percentile(v, [1, 99]) if color_by == "psi" else (0.0, np.percentile(v, 99))
            self._memo[key] = (float(lo), float(hi) if hi > lo else float(lo) + 1.0)
        return self._memo[key]

    def field_range(self, name: str, level: int = 0) -> tuple[float, float]:
        """Colour range of a field: its 1st to 99th percentile over the grid (fixed while slicing through it)."""
        key = ("range", name, level if name == "psi" else 0)
        if key not in self._memo:
            lo, hi = np.percentile(self.field(name, level)[::2, ::2, ::2], [1, 99])
            self._memo[key] = (float(lo), float(hi) if hi > lo else float(lo) + 1.0)
        return self._memo[key]

    # -- coarse input -----------------------------------------------------------------------

    @cached_property
    def exterior(self) -> Surface:
        from fracture.io.ply import read_ply

        V, F, _, fd = self._read(layout.EXTERIOR, "the exterior", read_ply)
        return Surface(V, F, {"component": fd.get("component", np.zeros(len(F), np.int64))})

    @cached_property
    def solid(self):
        """B with its winding-number hierarchy, built on the first inside test (the slice's mask)."""
        from fracture.mesh.exterior import Exterior

        return Exterior(self.exterior.V, self.exterior.F)

    @cached_property
    def coarse_fracture(self) -> Surface:
        from fracture.io.ply import read_ply

        V, F, _, _ = self._read(layout.COARSE_SURFACE, "the coarse fracture surface", read_ply)
        return Surface(V, F)

    @cached_property
    def refined_fracture(self) -> Surface | None:
        from fracture.io.ply import read_ply

        if not self.has(layout.REFINED_SURFACE):
            return None
        V, F, _, _ = self._read(layout.REFINED_SURFACE, "the refined fracture surface", read_ply)
        return Surface(V, F)

    @cached_property
    def coarse_animation(self):
        from fracture.coarse.animation import CoarseAnimation

        lo, hi, nodes = (self._read(rel, "the coarse animation", np.load)
                         for rel in (layout.ANIMATION_LO, layout.ANIMATION_HI, layout.ANIMATION_NODES))
        return CoarseAnimation(lo=lo, hi=hi, nodes=nodes)

    @cached_property
    def coarse_parts(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per component: the coarse exterior's vertex ids on it and its triangles over them."""
        ext = self.exterior
        out = []
        for c in range(self.coarse_animation.n_components):
            used, local = np.unique(ext.F[ext.scalars["component"] == c], return_inverse=True)
            out.append((used, local.reshape(-1, 3)))
        return out

    @cached_property
    def motion_points(self) -> np.ndarray:
        """Each coarse piece's convex hull corners at every frame: they hold the pieces' extremes
        throughout the animation (the pieces move rigidly or nearly)."""
        from scipy.spatial import ConvexHull, QhullError

        V, out = self.exterior.V, [np.zeros((0, 3))]
        for c, (used, _) in enumerate(self.coarse_parts):
            if len(used):
                P = V[used]
                try:
                    P = P[ConvexHull(P).vertices]
                except (QhullError, ValueError):  # flat or too few points: all of them
                    pass
                out.append(self.coarse_animation.trajectories(c, P).reshape(-1, 3))
        return np.concatenate(out)

    def coarse_pieces(self, t: int) -> list[Surface]:
        """The coarse exterior's triangles of each component, moved to frame ``t``."""
        V, anim = self.exterior.V, self.coarse_animation
        return [Surface(anim.deform(c, t, V[used]), F) for c, (used, F) in enumerate(self.coarse_parts)]

    # -- iterations -------------------------------------------------------------------------

    @property
    def has_iterations(self) -> bool:
        return self.has(layout.ITERATIONS_INDEX)

    @cached_property
    def iterations(self) -> list[dict]:
        from fracture.io.snapshots import load_snapshots

        return self._read(layout.ITERATIONS_INDEX, "the iteration view", lambda _: load_snapshots(self.dir))

    @property
    def energy(self) -> list[float]:
        """The functional the flow minimises at each snapshot, the first (the coarse surface) included."""
        return list(self.manifest.get("stats", {}).get("refine", {}).get("functional", []))

    @property
    def stages(self) -> list[int]:
        """The refinement's stage at each snapshot (-1: the global search's surface)."""
        return list(self.manifest.get("stats", {}).get("refine", {}).get("stage", []))

    @cached_property
    def iteration_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The box holding the fracture surface at every iteration."""
        lo = np.min([it["positions"].min(axis=0) for it in self.iterations], axis=0).astype(np.float64)
        hi = np.max([it["positions"].max(axis=0) for it in self.iterations], axis=0).astype(np.float64)
        return lo, hi

    def iteration(self, k: int) -> Surface:
        its = self.iterations
        if not 0 <= k < len(its):
            raise InputError(f"iteration must be in 0..{len(its) - 1}, got {k}")
        s = its[k]
        return Surface(s["positions"], s["faces"], {"psi": s["psi"], "speed": s["speed"]})

    # -- animation --------------------------------------------------------------------------

    @property
    def has_animation(self) -> bool:
        return self.has(layout.TRANSFER)

    @cached_property
    def transfer(self):
        from fracture.pieces.transfer import load_transfer

        return self._read(layout.TRANSFER, "the animation view", load_transfer)

    @cached_property
    def _piece_files(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Each piece's (material-space vertices, triangles, exterior flag per triangle)."""
        from fracture.io.ply import read_ply

        out = []
        for c in range(len(self.transfer.offsets) - 1):
            V, F, _, fd = self._read(layout.piece(c), "the animation view", read_ply)
            ext = np.asarray(fd.get("exterior", np.ones(len(F))), bool)
            out.append((V, F.astype(np.int64), ext))
        return out

    @property
    def piece_faces(self) -> list[np.ndarray]:
        """Each piece's triangles, indexing its rows of the transfer (``transfer.piece``)."""
        return [F for _, F, _ in self._piece_files]

    def pieces_rest(self) -> list[Surface]:
        """The high-resolution pieces in material space (as assembled), with ``exterior`` face flags."""
        return [Surface(V, F, {"exterior": ext}) for V, F, ext in self._piece_files]

    @property
    def n_frames(self) -> int:
        return self.transfer.n_frames if self.has_animation else 0

    def pieces_at(self, t: int) -> list[Surface]:
        """The high-resolution pieces at frame ``t`` (0-based)."""
        tr = self.transfer
        if not 0 <= t < tr.n_frames:
            raise InputError(f"frame must be in 1..{tr.n_frames}, got {t + 1}")
        X = tr.positions(t)
        return [Surface(tr.piece(X, c), F, {"exterior": ext})
                for c, (_, F, ext) in enumerate(self._piece_files)]

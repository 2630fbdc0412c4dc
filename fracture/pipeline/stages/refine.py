"""The ``refine`` stage: evolve and refine the coarse fracture surface (Sections 4.3, 4.4).

Outputs (material space):

* ``refined/fracture_surface.ply``: the refined surface, with the two
  components each triangle separates (face properties ``side0``, ``side1``);
* ``refined/tree.npz``: the barycentric tree (``parents``, ``weights``,
  ``created`` per new vertex in creation order) and its composed sparse map
  from the coarse vertices (CSR ``data``, ``indices``, ``indptr``, ``shape``);
* snapshots for the viewer: per iteration the
  positions, psi and speed per vertex and the triangles, concatenated into
  four ``.npy`` arrays with ``refined/iterations.json`` giving the offsets
  (plain ``.npy``: no archive timestamps, the bytes depend on the data only).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from fracture.io import layout
from fracture.io.ply import write_ply
from fracture.refine import kernels_cached
from fracture.refine.engine import Refiner, default_search
from fracture.refine.untangle import require_uncrossed
from fracture.mesh.fracture_surface import FractureSurface
from fracture.pipeline.context import RunContext
from fracture.pipeline.typed import refine_params

_log = logging.getLogger(__name__)


def refine_stage(ctx: RunContext) -> None:
    cf = ctx.products.coarse
    fs = ctx.products.fields
    config = ctx.config
    params = refine_params(config)
    mesh = FractureSurface.from_coarse(cf.V, cf.F, cf.sides)
    BV, BF = ctx.products.exterior
    grain = getattr(fs, "grain", None)
    refiner = Refiner(mesh, fs.pyramid, BV, BF, params, np.random.default_rng(config.seed), grain=grain,
                      search=default_search(params, distance=fs.field("distance"), names=cf.names, grain=grain))
    snaps = Snapshots() if config.refine.snapshots else None
    if snaps is not None:
        snaps.add(refiner)
    if not kernels_cached():
        ctx.say("refine: compiling the refinement kernels (once per install, about a minute) ...")
    with ctx.bar(params.iterations, "refine") as bar:  # an upper bound: stages end when they settle
        def progress(it, r):
            if snaps is not None:
                snaps.add(r)
            bar.set_postfix_str(f"{len(r.mesh.F)} triangles")
            bar.update()
            _log.debug("iteration %d: %d triangles, functional %.6g, mean move %.3g cells", it + 1, len(r.mesh.F),
                       r.log.functional[-1], r.log.mean_move[-1])
            if ctx.listener is not None:
                ctx.tell("iteration", iteration=it + 1, positions=r.mesh.V.copy(), faces=r.mesh.F.copy(),
                         psi=r.psi.copy(), speed=np.linalg.norm(r.velocity, axis=1), energy=r.log.functional[-1])
        log = refiner.run(progress)
        bar.total = bar.n  # the surface settled: the bar ends full at the iterations it took
        bar.set_postfix_str(f"{len(mesh.F)} triangles, {log.stop}")
        bar.refresh()
    _log.info("refine: %d triangles after %d iterations; %s", len(mesh.F), log.iterations, log.stop)
    # no crossing pair leaves the refinement: relaxed apart, or the run is refused (fracture/refine/untangle.py)
    mesh.V, crossed = require_uncrossed(mesh.V, mesh.F, refiner.B)
    ctx.products.refined = mesh

    write_ply(ctx.path(layout.REFINED_SURFACE), mesh.V, mesh.F,
              face_data={"side0": mesh.sides[:, 0].astype(np.int32), "side1": mesh.sides[:, 1].astype(np.int32)})
    W = mesh.tree_matrix()
    empty = np.zeros((0, 3))
    tree = dict(
        n_coarse=np.int64(mesh.n_coarse),
        parents=np.concatenate(mesh.parents) if mesh.parents else empty.astype(np.int64),
        weights=np.concatenate(mesh.weights) if mesh.weights else empty,
        created=np.concatenate(mesh.created) if mesh.created else empty,
        map_data=W.data, map_indices=W.indices.astype(np.int64), map_indptr=W.indptr.astype(np.int64),
        map_shape=np.array(W.shape, np.int64),
    )
    ctx.save_npz(layout.TREE, tree)
    if snaps is not None:
        snaps.save(ctx, layout.ITERATIONS)

    ctx.counts.update(refined_fracture_triangles=int(len(mesh.F)), refined_fracture_vertices=int(len(mesh.V)),
                      iterations=log.iterations)
    ctx.stats["refine"] = {
        "stopped_because": log.stop,
        # per iteration, entry 0 the coarse surface (see fracture.refine.engine.IterationLog)
        "stage": [int(s) for s in log.stage],
        "functional": [float(e) for e in log.functional],
        "functional_before_step": [float(e) for e in log.functional_before],
        "energy": [float(e) for e in log.energy],
        "area": [float(a) for a in log.area],
        "triangles": [int(t) for t in log.triangles],
        "mean_move_cells": [float(m) for m in log.mean_move],
        "max_move_cells": [float(m) for m in log.max_move],
        "tau": [float(t) for t in log.tau],
        "step_retries": [int(r) for r in log.retries],
        "splits": [int(s) for s in log.splits],
        "stopped_by_collisions": [int(s) for s in log.stopped],
        # the last iteration's (flips keep the boundary); measured afresh when no iteration ran
        "max_boundary_distance": float(log.boundary_error[-1] if log.boundary_error else refiner.boundary_error()),
        "self_intersecting_pairs": 0,  # require_uncrossed: none, or no run
        "crossing_pairs_relaxed": int(crossed),
        "phase_seconds": {k: round(v, 4) for k, v in log.seconds.items()},
        "search": _search_stats(log.search),
    }
    if log.search is not None:
        ctx.notes.extend(log.search.notes)
    if crossed:
        ctx.notes.append(f"refine: {crossed} pairs of refined triangles crossed each other; relaxed apart")


def _search_stats(result) -> dict | None:
    """The manifest's record of the global search (None when there was none)."""
    if result is None:
        return None
    return {
        "replaced_coarse_surface": result.surface is not None,
        "free_nodes": result.free_nodes,
        "labels_changed": result.labels_changed,
        "cut_energy": [float(e) for e in result.cut_energy],
        "functional_coarse_and_searched": [float(e) for e in result.functional],
        "functional_sampled_coarse_and_searched": [float(e) for e in result.sampled],
        "travel_mean_cells": float(result.travel.mean()) if len(result.travel) else 0.0,
        "seconds": {k: round(v, 4) for k, v in result.seconds.items()},
        "notes": list(result.notes),
    }


class Snapshots:
    """Per-iteration positions, triangles, psi and speed, kept compact (float32, int32)."""

    def __init__(self):
        self.V, self.F, self.psi, self.speed = [], [], [], []

    def add(self, r: Refiner) -> None:
        m = r.mesh
        self.V.append(m.V.astype(np.float32))
        self.F.append(m.F.astype(np.int32))
        self.psi.append(r.psi.astype(np.float32))
        self.speed.append(np.linalg.norm(r.velocity, axis=1).astype(np.float32))

    def save(self, ctx: RunContext, stem: str) -> None:
        nv = np.cumsum([0] + [len(v) for v in self.V])
        nf = np.cumsum([0] + [len(f) for f in self.F])
        ctx.save_array(f"{stem}_positions.npy", np.concatenate(self.V))
        ctx.save_array(f"{stem}_faces.npy", np.concatenate(self.F))
        ctx.save_array(f"{stem}_psi.npy", np.concatenate(self.psi))
        ctx.save_array(f"{stem}_speed.npy", np.concatenate(self.speed))
        ctx.save_json(f"{stem}.json", {"vertex_offsets": nv.tolist(), "face_offsets": nf.tolist(),
                                       "snapshots": len(self.V)})


def load_snapshots(run_dir, stem: str = layout.ITERATIONS) -> list[dict]:
    """The snapshots of a run: per iteration a dict of positions, faces, psi, speed."""
    base = Path(run_dir) / stem
    meta = json.loads(base.with_suffix(".json").read_text())
    arrays = {k: np.load(f"{base}_{k}.npy") for k in ("positions", "faces", "psi", "speed")}
    nv, nf = meta["vertex_offsets"], meta["face_offsets"]
    return [{"positions": arrays["positions"][nv[i]:nv[i + 1]], "faces": arrays["faces"][nf[i]:nf[i + 1]],
             "psi": arrays["psi"][nv[i]:nv[i + 1]], "speed": arrays["speed"][nv[i]:nv[i + 1]]}
            for i in range(meta["snapshots"])]

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

import logging

import numpy as np

from fracture.io import layout
from fracture.io.ply import write_ply
from fracture.io.snapshots import Snapshots
from fracture.refine import kernels_cached
from fracture.refine.engine import Refiner, default_search
from fracture.refine.untangle import require_uncrossed
from fracture.mesh.fracture_surface import FractureSurface
from fracture.pipeline.context import RunContext

_log = logging.getLogger(__name__)


def refine_stage(ctx: RunContext) -> None:
    cf = ctx.products.coarse
    fs = ctx.products.fields
    config = ctx.config
    params = config.refine.params()
    mesh = FractureSurface.from_coarse(cf.V, cf.F, cf.sides)
    BV, BF = ctx.products.exterior
    grain = getattr(fs, "grain", None)
    bands = _Cached(ctx, "search band", (config.refine.band, config.refine.core)) if ctx.cache is not None else None
    volumes = _Cached(ctx, "coarse volumes") if ctx.cache is not None else None
    coarse_volumes = None if volumes is None else volumes.get()
    # draw 0 is the seed's own generator; another draw one derived from both (the material keeps the seed)
    draw = config.refine.draw
    rng = np.random.default_rng(config.seed if draw == 0 else [config.seed, draw])
    refiner = Refiner(mesh, fs.pyramid, BV, BF, params, rng, grain=grain,
                      search=default_search(params, distance=fs.field("distance"), names=cf.names, grain=grain,
                                            bands=bands),
                      coarse_volumes=coarse_volumes)
    if volumes is not None and coarse_volumes is None and refiner.volumes is not None:
        volumes.put(refiner.volumes.coarse)
    snaps = Snapshots() if config.refine.snapshots else None
    if snaps is not None:
        snaps.add(mesh.V, mesh.F, refiner.psi, np.linalg.norm(refiner.velocity, axis=1))
    if not kernels_cached():
        ctx.say("refine: compiling the refinement kernels (once per install, about a minute) ...")
    with ctx.bar(params.iterations, "refine") as bar:  # an upper bound: stages end when they settle
        def progress(it, r):
            if snaps is not None:
                snaps.add(r.mesh.V, r.mesh.F, r.psi, np.linalg.norm(r.velocity, axis=1))
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
    mesh.V, crossed, crossing = require_uncrossed(mesh.V, mesh.F, refiner.B)
    ctx.products.refined = mesh

    write_ply(ctx.path(layout.REFINED_SURFACE), mesh.V, mesh.F,
              face_data={"side0": mesh.sides[:, 0].astype(np.int32), "side1": mesh.sides[:, 1].astype(np.int32)})
    ctx.save_npz(layout.TREE, mesh.tree_arrays(), compress=True)
    if snaps is not None:
        snaps.save(ctx)

    ctx.counts.update(refined_fracture_triangles=int(len(mesh.F)), refined_fracture_vertices=int(len(mesh.V)),
                      iterations=log.iterations)
    ctx.stats["refine"] = {
        "stopped_because": log.stop,
        # per iteration, entry 0 the coarse surface (see fracture.refine.engine.IterationLog)
        "stage": [int(s) for s in log.stage],
        "functional": [float(e) for e in log.functional],
        "functional_before_step": [float(e) for e in log.functional_before],
        # level 0's, on dense samples of the coarse and the refined surface (comparable across meshes)
        "functional_sampled_coarse_and_refined": [float(e) for e in log.sampled],
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
        "self_intersecting_pairs": int(crossing),  # counted by require_uncrossed (any left: no run)
        "crossing_pairs_relaxed": int(crossed),
        "phase_seconds": {k: round(v, 4) for k, v in log.seconds.items()},
        "search": _search_stats(log.search),
        # each piece's volume at the end as a share of its coarse volume (followed through the steps)
        "piece_volume_shares": ([] if refiner.volumes is None else
                                [round(float(v), 4) for v in refiner.volumes.shares()]),
    }
    if log.search is not None:
        ctx.notes.extend(log.search.notes)
    if crossed:
        ctx.notes.append(f"refine: {crossed} pairs of refined triangles crossed each other; relaxed apart")
    ctx.notes.extend(_outcome_notes(params, log, len(cf.F), refiner.searched))
    ctx.notes.extend(_volume_notes(refiner.volumes, cf.names))


def _outcome_notes(params, log, coarse_triangles: int, searched: bool) -> list[str]:
    """What a user should know of a refinement that did not do what its config suggests: no flow step, no room
    to split, a result the functional scores worse than the coarse surface."""
    notes = []
    start = "searched" if searched else "coarse"
    if params.iterations == 0:
        notes.append(f"refine: refine.iterations is 0: no flow step ran; the {start} surface is the result")
    if params.max_triangles <= coarse_triangles:
        notes.append(f"refine: refine.max_triangles ({params.max_triangles}) is not above the coarse surface's "
                     f"{coarse_triangles} triangles: nothing was split")
    coarse, refined = log.sampled
    on_b = log.sampled_on_b
    if refined > coarse and 0.0 < refined <= on_b:
        notes.append(f"refine: the refined surface scores higher on the functional than the coarse one ({refined:.6g} "
                     f"against {coarse:.6g}, sampled alike), whose rims cut across B's curves: fitted onto B the "
                     f"coarse surface scores {on_b:.6g}, and the flow lowered it from there")
    elif refined > coarse:
        own = log.functional[-1] < log.functional[0]
        notes.append(f"refine: the refined surface scores higher on the functional than the coarse one ({refined:.6g} "
                     f"against {coarse:.6g}, sampled alike)" + (
                         "; the flow lowered it as it measures it (psi at the vertices), not on dense samples"
                         if own else ""))
    return notes


def _volume_notes(volumes, names: list[str]) -> list[str]:
    """The pieces whose volume the flow held at their share of the coarse volume (refine.keep_volume)."""
    if volumes is None or not volumes.held:
        return []
    held = sorted(volumes.held)
    many = len(held) > 1
    ends = ", ".join(f"{names[c]!r} {100 * volumes.shares()[c]:.0f} %" for c in held)
    return [f"refine: the flow held piece{'s' if many else ''} {', '.join(repr(names[c]) for c in held)} at "
            f"{100 * volumes.keep:.0f} % of {'their' if many else 'its'} coarse volume (refine.keep_volume), "
            f"where the material would have shrunk {'them' if many else 'it'} further; at the end {ends}"]


class _Cached:
    """What the refinement makes of the coarse surface, B and the grid alone, in the stage cache under the coarse
    stage's key, the grid and ``extra`` (the parameters it reads): the search's band
    (:func:`fracture.refine.search.search_band`; ``extra`` the band's and the core's widths) and the pieces'
    coarse volumes (:func:`fracture.refine.volumes.measure_volumes`). Neither reads psi, so a re-run with the
    material or the stress changed (the viewer's, a sweep's) reuses them."""

    def __init__(self, ctx: RunContext, name: str, extra=()):
        from fracture.pipeline.cache import code_version, digest
        from fracture.pipeline.stages.fields import grid_inputs

        self.cache, self.name = ctx.cache, name
        self.key = digest(name, ctx.keys["coarse"], grid_inputs(ctx.config.tree()), tuple(extra), code_version())

    def get(self):
        return self.cache.value(self.name, self.key)

    def put(self, value) -> None:
        self.cache.keep(self.name, self.key, value)


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
        "cut_against_band_limits": round(float(result.pressed), 4),
        "seconds": {k: round(v, 4) for k, v in result.seconds.items()},
        "notes": list(result.notes),
    }

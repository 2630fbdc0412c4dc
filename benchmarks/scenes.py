"""What the scene benchmarks share: a scene with its fields, and one process per scene.

Each scene runs in a fresh process so that its peak memory is its own and
one scene's caches do not speed up the next.
"""

from __future__ import annotations

import multiprocessing as mp
import queue
from pathlib import Path

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def scene_with_fields(name: str, overrides: list[str]):
    """The resolved config, the coarse input and the fields of built-in scene ``name``."""
    from fracture.pipeline.config import load_config
    from fracture.coarse.scenes import build_scene
    from fracture.pipeline.stages.fields import fields_from_config

    cfg = load_config(CONFIGS / f"{name}.yaml", overrides)
    cf = build_scene(name, cfg.seed, cfg.input.frames, cfg.input.separation)
    return cfg, cf, fields_from_config(cfg, cf.exterior_V, cf.V, cf.F)


def refine(cfg, cf, fs):
    """Refine the coarse fracture surface of ``cf``; returns the mesh and the iteration log."""
    import numpy as np

    from fracture.refine.engine import Refiner, default_search
    from fracture.mesh.fracture_surface import FractureSurface
    mesh = FractureSurface.from_coarse(cf.V, cf.F, cf.sides)
    params = cfg.refine.params()
    grain = getattr(fs, "grain", None)  # as the refine stage passes it (fracture/pipeline/stages/refine.py)
    log = Refiner(mesh, fs.pyramid, cf.exterior_V, cf.exterior_F, params, np.random.default_rng(cfg.seed), grain=grain,
                  search=default_search(params, distance=fs.field("distance"), names=cf.names, grain=grain)).run()
    return mesh, log


def checked_configs(scenes, overrides: list[str]) -> None:
    """Load every scene's config with ``overrides`` before any process starts: a wrong key or value ends the
    benchmark with the loader's one line (file or ``--set``, key, what was given and expected), not a
    traceback in a child process."""
    from fracture.errors import ConfigError
    from fracture.pipeline.config import load_config

    for name in scenes:
        try:
            load_config(CONFIGS / f"{name}.yaml", overrides)
        except ConfigError as exc:
            raise SystemExit(f"error: {exc}") from None


def in_processes(target, scenes, *args):
    """Yield ``(scene, result)`` where ``target(scene, *args, queue)`` puts its result on the queue, one process each
    (started with ``spawn``: a fresh interpreter, no threads or locks inherited from this one). A process that
    ends without a result (its error printed by it) ends the benchmark, naming the scene, instead of leaving this
    one waiting for it."""
    ctx = mp.get_context("spawn")
    for name in scenes:
        q = ctx.Queue()
        p = ctx.Process(target=_prepared, args=(target, name, *args, q))
        p.start()
        while True:
            try:
                result = q.get(timeout=1.0)
                break
            except queue.Empty:
                if not p.is_alive() and q.empty():
                    raise SystemExit(f"error: the process of scene {name!r} ended without a result (exit code "
                                     f"{p.exitcode}); its error is above")
        p.join()
        yield name, result


def _prepared(target, *args) -> None:
    """``target(*args)`` in a process set up as the command line's (fracture.process.prepare_process)."""
    from fracture.process import prepare_process

    prepare_process()
    target(*args)

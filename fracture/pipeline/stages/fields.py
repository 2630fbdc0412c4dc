"""The ``fields`` stage: zeta, xi, psi and the strength pyramid on a grid."""

from __future__ import annotations

import numpy as np

from fields.build import build_fields, fields_memory, grid_for
from fields.pyramid import StrengthPyramid
from fields.slices import axis_slice, slice_image
from fracture.errors import ConfigError
from fracture.io import layout
from fracture.pipeline.context import RunContext
from fracture.pipeline.schema import Config

PREVIEW_FIELDS = ("zeta", "xi", "psi")
# Target width in pixels of one preview slice (pixels are repeated up to it).
_PREVIEW_WIDTH = 400
_PREVIEW_GAP = 8


def fields_from_config(cfg: Config, BV: np.ndarray, SV: np.ndarray, SF: np.ndarray, step=None, zeta=None,
                       distance=None, pyramids=None):
    """:func:`fields.build.build_fields` with the parameters of a resolved config (``zeta``, ``distance`` and
    ``pyramids``: parts known already, see there)."""
    c = cfg
    return build_fields(
        BV, SV, SF,
        resolution=c.grid.resolution,
        padding=c.grid.padding,
        min_across=c.grid.min_across,
        layers=c.strength.layers,
        seed=c.seed,
        normalize=c.strength.normalize,
        stress_length=c.stress.length,
        strength_weight=c.psi.strength_weight,
        stress_weight=c.psi.stress_weight,
        levels=c.pyramid.levels,
        sigma=c.pyramid.sigma,
        step=step,
        zeta=zeta,
        distance=distance,
        pyramids=pyramids,
    )


def check_grid_memory(cfg: Config, BV: np.ndarray) -> None:
    """Refuse, before allocating, a grid whose fields need more than ``grid.max_memory_gb``."""
    c = cfg
    grid = grid_for(BV, c.grid.resolution, c.grid.padding, c.grid.min_across)
    need = fields_memory(grid.size, c.pyramid.levels) / 1e9
    if need > c.grid.max_memory_gb:
        shape = "x".join(str(n) for n in grid.shape)
        thin = grid.size > grid_for(BV, c.grid.resolution, c.grid.padding).size  # min_across made the cells
        gb = f"{need:.1f}" if need >= 0.1 else f"{need:.2g}"  # a tiny limit: not "0.0 GB, more than 0.01"
        raise ConfigError("config", "grid.min_across" if thin else "grid.resolution",
                          f"{c.grid.min_across if thin else c.grid.resolution} gives a {shape} grid ({grid.size:,} "
                          f"nodes) whose fields need about {gb} GB, more than grid.max_memory_gb "
                          f"({c.grid.max_memory_gb:g} GB); expected " + (
                              "fewer nodes across the object's thinnest extent" if thin else "a lower resolution")
                          + ", or raise the limit if this machine has the memory")


def fields_stage(ctx: RunContext) -> None:
    cfg = ctx.config
    (BV, BF), cf = ctx.products.exterior, ctx.products.coarse
    check_grid_memory(cfg, BV)
    known = cached_parts(ctx) if ctx.cache is not None else {}
    with ctx.bar(3, "fields") as bar:
        fs = fields_from_config(cfg, BV, cf.V, cf.F, step=lambda name: (bar.set_postfix_str(name), bar.update()),
                                **known)
    for name in ("zeta", "distance"):
        if ctx.cache is not None and name not in known:
            ctx.cache.keep(name, known_key(ctx, name), fs.field(name))
    ctx.products.fields = fs
    plain = _uniform_material(cfg, fs.field("zeta"))
    if plain:
        ctx.notes.append(plain)

    ctx.save_json(layout.GRID, fs.grid.to_dict())
    for name in PREVIEW_FIELDS:
        ctx.save_array(layout.field(name), fs.field(name).astype(np.float32))
    ctx.save_array(layout.PYRAMID, fs.pyramid.levels.astype(np.float32))
    ctx.save_png(layout.PREVIEW, preview_image(fs, ctx.config.preview))

    ctx.counts.update(
        grid_nodes=fs.grid.size,
        pyramid_levels=fs.pyramid.n_levels,
        exterior_triangles=int(len(BF)),
    )
    ctx.stats["fields"] = {
        "grid_shape": list(fs.grid.shape),
        **{f"{n}_range": [float(fs.field(n).min()), float(fs.field(n).max())] for n in PREVIEW_FIELDS},
    }


def _uniform_material(cfg: Config, zeta: np.ndarray) -> str | None:
    """A note when the material gives the refinement nothing to find: zeta the same everywhere, or weighed 0."""
    if cfg.psi.strength_weight == 0:
        why = "psi.strength_weight is 0"
    elif float(np.ptp(zeta)) <= _UNIFORM * max(1.0, float(np.abs(zeta).max())):
        why = f"the strength layers give zeta = {float(zeta.flat[0]):.6g} everywhere"
    else:
        return None
    grain = any(layer.kind == "grain" for layer in cfg.strength.layers)
    return (f"fields: {why}: the material has no weak places for the cracks to find; they follow the stress "
            + ("and the grain's fibres alone" if grain else "alone (the coarse surface, smoothed)"))


# zeta's range, relative to its size, below which the material is one strength
_UNIFORM = 1e-9


def known_key(ctx: RunContext, name: str) -> str:
    """The cache key of a part of the fields of this run: the strength field ``zeta``, the distances
    ``distance`` to the coarse fracture surface, or the pyramids of zeta (``zeta pyramid``) and of the stress
    (``xi pyramid``): what each depends on of the config, and the coarse stage (its exterior and surface)."""
    from fracture.pipeline.cache import code_version, digest

    cfg = ctx.config.tree()
    depends = {"zeta": (cfg["strength"], cfg["seed"]), "distance": (),
               "zeta pyramid": (cfg["strength"], cfg["seed"], cfg["pyramid"]),
               "xi pyramid": (cfg["stress"], cfg["pyramid"])}[name]
    return digest(name, ctx.keys["coarse"], grid_inputs(cfg), depends, code_version())


def grid_inputs(cfg: dict) -> tuple:
    """What of a config's tree (``Config.tree()``) the field grid is made of, beside the coarse stage's
    exterior (``fields.build.grid_for``): for the keys of what is kept per grid."""
    return cfg["grid"]["resolution"], cfg["grid"]["padding"], cfg["grid"]["min_across"]


def cached_parts(ctx: RunContext) -> dict:
    """The strength field, the distances and the pyramids from the cache (where a run with the same inputs
    made them; a pyramid the cache does not have is built and kept)."""
    values = {name: ctx.cache.value(name, known_key(ctx, name)) for name in ("zeta", "distance")}
    known = {name: v for name, v in values.items() if v is not None}
    config = ctx.config

    def pyramid(name: str, grid, field: np.ndarray) -> StrengthPyramid:
        key = known_key(ctx, f"{name} pyramid")
        made = ctx.cache.value("pyramid", key)
        if made is None:
            made = StrengthPyramid(grid, field, levels=config.pyramid.levels, sigma=config.pyramid.sigma)
            ctx.cache.keep("pyramid", key, made)
        return made

    return {**known, "pyramids": pyramid}


def preview_image(fs, preview) -> np.ndarray:
    """zeta, xi and psi side by side on one slice plane, as an RGB image."""
    axis = preview.axis
    if axis is None:
        axis = int(np.argmin(fs.grid.shape))
    panels = []
    for name in PREVIEW_FIELDS:
        plane, _ = axis_slice(fs.grid, fs.field(name), axis, preview.offset)
        scale = max(1, _PREVIEW_WIDTH // plane.shape[0])
        panels.append(slice_image(plane, preview.colormap, scale=scale))
    height = panels[0].shape[0]
    gap = np.full((height, _PREVIEW_GAP, 3), 255, np.uint8)
    row = [panels[0]]
    for p in panels[1:]:
        row += [gap, p]
    return np.concatenate(row, axis=1)

"""The pipeline's stages, in order: :data:`STAGES`."""

from __future__ import annotations

from typing import Callable, NamedTuple

from fracture.pipeline.context import RunContext
from fracture.pipeline.stages.animate import animate_stage
from fracture.pipeline.stages.coarse import coarse_stage
from fracture.pipeline.stages.fields import fields_stage
from fracture.pipeline.stages.refine import refine_stage


class Stage(NamedTuple):
    """A stage: its name (the manifest's, ``--until``'s, the cache's) and what it does to the context."""

    name: str
    run: Callable[[RunContext], None]


STAGES: tuple[Stage, ...] = (
    Stage("coarse", coarse_stage),  # Sec. 4.1: the coarse fracture animation
    Stage("fields", fields_stage),  # Sec. 4.2-4.3: strength, stress, psi and its pyramid
    Stage("refine", refine_stage),  # Sec. 4.3-4.4: the refined fracture surface
    Stage("animate", animate_stage),  # Sec. 5: watertight pieces with the coarse motion
)

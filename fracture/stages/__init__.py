"""Pipeline stages; importing this package registers them with the runner."""

from fracture.stages import animate, coarse, fields, refine  # noqa: F401

"""Pipeline stages; importing this package registers them with the runner."""

from fracture.stages import coarse, fields, refine  # noqa: F401

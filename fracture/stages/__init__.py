"""Pipeline stages; importing this package registers them with the runner."""

from fracture.stages import coarse, fields  # noqa: F401

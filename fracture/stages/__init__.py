"""Pipeline stages; importing this package registers them with the runner."""

from fracture.stages import fields  # noqa: F401

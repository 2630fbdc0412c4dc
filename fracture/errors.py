"""Errors that reach the user as one clear line (the CLI prints them without a traceback)."""

from fracture.schema import ConfigError


class InputError(ValueError):
    """An input file or array is unusable; the message says where and why."""


class StageError(ValueError):
    """A stage name on the command line is unknown or not available."""


__all__ = ["ConfigError", "InputError", "StageError"]

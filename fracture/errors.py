"""Errors that reach the user as one clear line (the CLI prints them without a traceback)."""

from fields.errors import InputError  # raised by the fields too, which import nothing from here
from fracture.pipeline.schema import ConfigError


class StageError(ValueError):
    """A stage name on the command line is unknown or not available."""


class ResultError(ValueError):
    """A result failed the checks a run makes before it succeeds (a piece not closed, crossing itself, ...).

    The message names the piece and the failed check; the run writes nothing.
    """


__all__ = ["ConfigError", "InputError", "ResultError", "StageError"]

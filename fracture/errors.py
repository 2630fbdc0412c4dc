"""Errors that reach the user as one clear line (the CLI prints them without a traceback)."""

from fields.errors import InputError  # raised by the fields too, which import nothing from here


class ConfigError(ValueError):
    """A config value is missing, unknown, of the wrong type or out of range.

    Parameters
    ----------
    where : str
        The file (or ``--set``) the offending value came from.
    key : str
        Dotted key path, e.g. ``strength.layers[0].frequency``.
    problem : str
        What is wrong, including what was given and what was expected.
    """

    def __init__(self, where: str, key: str, problem: str):
        self.where, self.key, self.problem = where, key, problem
        super().__init__(f"{where}: {key}: {problem}" if key else f"{where}: {problem}")


class JoinError(InputError):
    """The refined fracture surface cannot be joined to the object's surface: its cracks' rims cannot be cut
    into B (:mod:`fracture.pieces.imprint`).

    Parameters
    ----------
    where : str
        The stage.
    problem : str
        What could not be joined, and where.
    advice : str
        What to change, appended to the message.
    """

    def __init__(self, where: str, problem: str, advice: str = ""):
        self.where, self.problem = where, problem
        super().__init__(f"{where}: {problem}{advice}")


class StageError(ValueError):
    """A stage name on the command line is unknown or not available."""


class ResultError(ValueError):
    """A result failed the checks a run makes before it succeeds (a piece not closed, crossing itself, ...).

    The message names the piece and the failed check; the run writes nothing.
    """


__all__ = ["ConfigError", "InputError", "JoinError", "ResultError", "StageError"]

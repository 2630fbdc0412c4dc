"""The error the fields raise on unusable input (:mod:`fracture.errors` re-exports it)."""


class InputError(ValueError):
    """An input file or array is unusable; the message says where and why."""

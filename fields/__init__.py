"""Material strength fields (Section 4.2) and the strength pyramid (Section 4.3).

Arrays in, arrays out: grids, procedural strength kinds, the stress estimate,
the modified field psi, its Gaussian pyramid and slices for display.

The names below are loaded from their modules on first use: a caller of a light
module (``fields.errors``, ``fields.params``, ``fields.grid``) does not pay for SciPy's
and numba's imports, which the command line's quick answers (a bad flag, a bad config)
would otherwise wait a second for.
"""

from importlib import import_module

_WHERE = {
    "FieldSet": "build", "build_fields": "build", "padded_bounds": "build",
    "Grid": "grid", "grid_shape_for_box": "grid",
    "trilinear": "interpolate",
    "StrengthPyramid": "pyramid",
    "axis_slice": "slices", "slice_image": "slices",
    "KINDS": "strength", "strength_field": "strength",
    "distance_to_surface": "stress", "modified_strength": "stress", "stress_from_distance": "stress",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(f"{__name__}.{_WHERE[name]}"), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))

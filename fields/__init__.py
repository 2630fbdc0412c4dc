"""Material strength fields (Section 4.2) and the strength pyramid (Section 4.3).

Arrays in, arrays out: grids, procedural strength kinds, the stress estimate,
the modified field psi, its Gaussian pyramid and slices for display.
"""

from fields.build import FieldSet, build_fields, padded_bounds
from fields.grid import Grid, grid_shape_for_box
from fields.interpolate import trilinear
from fields.pyramid import StrengthPyramid
from fields.slices import axis_slice, slice_image
from fields.strength import KINDS, strength_field
from fields.stress import distance_to_surface, modified_strength, stress_from_distance

__all__ = [
    "FieldSet", "Grid", "KINDS", "StrengthPyramid", "axis_slice", "build_fields", "distance_to_surface",
    "grid_shape_for_box", "modified_strength", "padded_bounds", "slice_image", "strength_field",
    "stress_from_distance", "trilinear",
]

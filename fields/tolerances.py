"""The tolerances of the fields (:mod:`fracture.tolerances` holds them with every other one)."""

from types import SimpleNamespace

tol = SimpleNamespace(
    # Relative to a bounding-box extent: two bounds closer than this are a
    # degenerate (flat) box along that axis.
    extent=1e-9,
    # Denominator guard when normalising a field to [0, 1]; a field whose
    # range is below this is constant and maps to 0.
    field_range=1e-12,
    # Absolute zero for lengths and areas in material units (object size ~1).
    zero=1e-12,
)

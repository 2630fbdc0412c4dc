"""The viewer's numerical tolerances, in one place, each with its reason (as
:mod:`fracture.tolerances` holds those of the computation)."""

from types import SimpleNamespace

view_tol = SimpleNamespace(
    # Axis ticks: a tick this close (in steps) past the end of the range still counts, so a range that
    # ends on a round number shows its last tick despite floating-point rounding.
    tick=1e-9,
    # Text rendered on white and on black: pixels less opaque than this are transparent (un-premultiplying
    # them would divide by nothing).
    opaque=1e-4,
    # Directions shorter than this are no direction (a camera whose eye is its centre; the floor of a
    # norm before a division).
    direction=1e-12,
    # An up vector whose part across the viewing direction is shorter than this (unit vectors) is taken
    # as along it, and another axis serves.
    across=1e-6,
    # Relative: a camera's up within this angle (radians, about) of its viewing direction is along it.
    parallel=1e-9,
    # A box thinner than this (world units) is given this width, so a flat object still has a floor.
    extent=1e-9,
    # The floor lies this far (relative to the box diagonal) below the object, so the two do not z-fight.
    floor_gap=1e-3,
    # The fitted eye stays at least this far (world units) in front of the middle depth it looks at.
    depth=1e-9,
)

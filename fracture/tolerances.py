"""Every numerical tolerance of the project, in one place.

Code never types an epsilon inline: it names one of these, so that the
choices can be read, reviewed and tuned together.
"""

from types import SimpleNamespace

from fields.tolerances import tol as _fields

tol = SimpleNamespace(
    **vars(_fields),  # extent, field_range, zero: the fields' own (fields/tolerances.py)
    # --- Importing piece meshes ---
    # |sum of area vectors| / total area above this: the piece is not closed.
    closure=1e-5,
)

# Imported motion: a rigid fit this close (relative to the diagonal) is taken
# as rigid; files round to 6 decimals.
tol.rigid_fit = 1e-5

# Repairs that move points by less than this (relative to the diagonal: the
# files' rounding) are not worth a note in the manifest.
tol.report = 1e-5

# Virtual fracture: a vertex of a boundary edge of the fracture surface
# farther than this from B (relative to the diagonal) is inside the object, and
# the edge is on a crack front; the bisection locating where an extended cut
# crosses B stops when its bracket is shorter than this (then projects onto B).
tol.on_surface = 1e-5

# Refinement: a boundary vertex farther than this from B (relative to the
# finest grid cell) is off B; the loop does not end while one is (a vertex
# split from a boundary edge starts on the chord and reaches B the iteration
# after, unless a collision stops its projection).
tol.on_b = 1e-9

# Input meshes: a triangle whose doubled area is at most this times the
# squared diagonal has no area (corners coinciding or on a line).
tol.degenerate = 1e-14

# Refinement: the static intersection tests of triangles (self-intersection
# checks, flips) count a contact within this fraction of the triangles'
# scale as a crossing: exact predicates are not needed on top of the
# continuous collision step, which keeps a thickness far above it.
tol.static_test = 1e-10

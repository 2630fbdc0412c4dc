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

# A decimal written to a file and read back lies within this fraction of its last digit of a whole number of
# them (the double's, or the single's, own error only): the file was written with that many decimals.
tol.decimal = 1e-3

# Repairs that move points by less than this (relative to the diagonal: the
# files' rounding) are not worth a note in the manifest.
tol.report = 1e-5

# Virtual fracture: a vertex of a boundary edge of the fracture surface
# farther than this from B (relative to the diagonal) is inside the object, and
# the edge is on a crack front; the bisection locating where an extended cut
# crosses B stops when its bracket is shorter than this (then projects onto B).
tol.on_surface = 1e-5

# The side of B from a closest point's pseudonormal (Exterior.inside_near): a barycentric weight of the
# closest point below this puts it on its triangle's edge (two: at a corner); a point closer to B than this
# (relative to B's diagonal: on B, to rounding) is answered by its winding number, as before, whatever it is.
tol.on_feature = 1e-9
tol.side_of_b = 1e-9

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

# A positive floor for denominators that can be zero (a degenerate triangle's
# area, a zero vector's length): anything it is compared with in a sound case
# is far above it, so it changes no result except a division by zero.
tol.tiny = 1e-300

# Refinement: a step is accepted when the minimised functional rises by no more
# than this fraction of its value (the rounding of its sums over the surface).
tol.functional_rise = 1e-12

# Edge flips: an edge is Delaunay when its opposite angles' cotangents sum to
# more than minus this (rounding of the cotangents).
tol.delaunay = 1e-12

# Continuous collisions (Bridson et al. 2002), relative tests:
# the coplanarity cubic is taken as quadratic when its leading coefficient is
# below this fraction of the others;
tol.cubic_leading = 1e-14
# a root of the cubic is this close (relative to its coefficients' scale) to zero;
tol.cubic_root = 1e-9
# barycentric and line-parameter slack when a vertex meets a triangle or two
# edges cross at the coplanar moment;
tol.contact_slack = 1e-9
# a triangle is degenerate (the edge-edge tests see it) below this relative
# Gram determinant, two edges parallel (the vertex-triangle tests see them)
# below the second;
tol.degenerate_gram = 1e-30
tol.parallel_edges = 1e-24
# the static segment-triangle test decides without square roots only when its
# squared tolerance is above this (a segment of zero length is tested fully).
tol.side_test_floor = 1e-200

# Imprint: a closest point within this fraction of its size of a surface
# vertex is that vertex.
tol.coincide = 1e-12

# Positions this close (relative to the diagonal) are one: a file's corners written twice, or points a
# boolean computed exactly and only rounding separates (the Voronoi cells of the built-in scenes).
tol.same_position = 1e-9

# A vertex this close to a bisector plane (relative to the diagonal) lies on it (the Voronoi cells).
tol.on_plane = 1e-7

# Imprinting B: a point within this barycentric distance of an edge (or two edges) of a B triangle is put
# on that edge (vertex): no sliver triangles of relative height below it; the point moves by at most this
# fraction of the height.
tol.snap = 1e-4

# Fans that cannot fold: a positive component, or a cross product that places a direction in a wedge,
# must exceed this fraction of the product of the lengths involved: far beyond rounding, so a pass is a
# proof.
tol.fan_margin = 1e-9

# Least-squares fits of the coarse motion (the lattice of a deforming piece) are solved to this relative
# accuracy: far below any motion a frame shows.
tol.lsqr = 1e-14

# Pieces' exact volumes and the Monte Carlo estimate may differ by five standard errors of the estimate
# and this share of B's volume (the estimate's own bias at few samples).
tol.volume_check = 1e-3

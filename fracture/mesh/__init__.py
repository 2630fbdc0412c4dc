"""Triangle-mesh queries every section uses: edge tables (edges), per-triangle areas and normals
(faces), edge bookkeeping and geometry in NumPy (topology), queries against the exterior B (exterior),
the static self-intersection count (intersect) on a hierarchical spatial hash (hashgrid, with Morton
codes: morton), vector helpers for compiled code (vec) and simple meshes (primitives)."""

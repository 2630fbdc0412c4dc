"""Triangle-mesh queries every section uses: edge bookkeeping and per-triangle geometry (topology),
the exterior surface's trees (exterior) and simple meshes (primitives)."""

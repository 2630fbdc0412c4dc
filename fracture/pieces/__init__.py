"""Section 5: watertight high-resolution pieces and the transfer of the coarse motion to them.

The exterior cut along the refined surface's boundary (imprint), the pieces
assembled from it and the refined surface (assembly), and the deformation
transfer (transfer).
"""

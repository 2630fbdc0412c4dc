"""Section 4.1: the coarse fracture animation in material space.

Its readers (per-frame meshes, USD) and built-in scenes, the shared
non-manifold fracture surface, the components it cuts the object into, virtual
fracture for incomplete cuts, and the components' motion.
"""

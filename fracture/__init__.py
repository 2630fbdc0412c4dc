"""Physics-inspired adaptive fracture refinement: the pipeline around the fields.

Kept free of imports so that leaf modules (``fracture.tolerances``,
``fracture.schema``) can be used by :mod:`fields` without import cycles.
"""

__version__ = "0.1.0"

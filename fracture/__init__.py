"""Physics-inspired adaptive fracture refinement (Chen, Yao, Feng, Wang, SIGGRAPH 2014): the
pipeline, on top of the material fields (:mod:`fields`).

Laid out by the paper:

- :mod:`fracture.coarse`: Section 4.1, the coarse fracture animation;
- :mod:`fracture.refine`: Sections 4.3 and 4.4, the refinement of the fracture surface;
- :mod:`fracture.pieces`: Section 5, watertight pieces and motion transfer;
- :mod:`fracture.mesh`, :mod:`fracture.io`: mesh queries and files;
- :mod:`fracture.pipeline`: configs, the runner and its stages, the cache, sweeps.

Importing a module changes nothing in the process (:mod:`fracture.process` holds the explicit
set-up calls). Library messages go to the ``fracture`` logger (:mod:`logging`), which has only a
:class:`~logging.NullHandler`: an application decides whether and where they appear (``fracref
--log-level info``).
"""

import logging

logging.getLogger(__name__).addHandler(logging.NullHandler())

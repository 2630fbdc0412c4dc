"""The refinement's parameters: one typed record that is both the code's parameter type and the
config's ``refine`` section (:mod:`fracture.pipeline.schema` extends it with the pipeline's own
keys). Lengths are in grid cells (the finest spacing)."""

from __future__ import annotations

from typing import Literal

from fields.params import Section, choice, integer, number


class RefineParams(Section):
    """Thresholds of the refinement (Sections 4.3, 4.4); see each field's description."""

    iterations: int = integer(60, 0, 10000, "largest number of iterations of the flow, all stages (a last stage "
                              "that ends above the coarse surface runs again from it, with stage_iterations of its "
                              "own)")
    stage_iterations: int = integer(15, 1, 10000, "largest number of iterations of one stage of the coarse-to-fine "
                                    "schedule")
    coarse_levels: int = integer(2, 1, 8, "every stage follows the mean of this many consecutive pyramid levels: the "
                                 "first the coarsest, each next one a level finer; the last stage follows level 0 "
                                 "alone; pyramid.levels gives one stage on every level (the paper's field)")
    tolerance: float = number(0.02, 0.0, 10.0, "a stage has settled when the mean vertex move of an iteration is "
                              "below this (grid cells) and it split at most 0.5 % of the triangles")
    step: float = number(0.5, 1e-4, 10.0, "nominal move per iteration (grid cells) where grad psi has its root mean "
                         "square")
    max_move: float = number(1.0, 1e-3, 10.0, "largest move of a vertex per iteration (grid cells)")
    fold: float = number(0.5, 1e-3, 0.9, "largest move of a triangle's corners relative to each other per iteration, "
                         "as a fraction of its smallest altitude (no triangle turns over within a step)")
    split_distance: float = number(0.15, 0.0, 10.0, "split where a sample leaves its triangle by more than this in a "
                                   "nominal step (grid cells): where psi varies across the triangle")
    tension: float = number(0.05, 1e-4, 10.0, "psi is shifted so its minimum is this fraction of its range (surface "
                            "tension)")
    min_edge: float = number(0.1, 1e-4, 10.0, "samples closer than this to a corner are skipped in the last stage "
                             "(grid cells; earlier stages keep half their finest level's width)")
    max_triangles: int = integer(200000, 10, 20_000_000, "no splits beyond this many triangles")
    thickness: float = number(1e-6, 0.0, 1.0, "closer than this counts as a collision (grid cells)")
    hold: int = integer(3, 0, 100, "iterations a vertex stopped by a collision stays stopped")
    search: Literal["graphcut", "none"] = choice(
        "none", "graphcut: before the flow, the band around the coarse surface is searched for the surface of least "
        "integral of psi by a minimum cut (fracture/refine/search.py), and the flow polishes it (polish_stages; its "
        "effect per scene: benchmarks/README.md; a searched surface of which no sound pieces can be made is "
        "refined again without the search, with a note); none: the flow alone, coarse to fine")
    band: float = number(14.0, 1.0, 200.0, "the search moves the surface at most this far from the coarse one (grid "
                         "cells; docs/design-measurements.md measures 10 to 16)")
    core: float = number(0.4, 0.0, 1.0, "the search leaves each piece the grid nodes farther from the coarse surface "
                         "than this fraction of the piece's depth (a minimum cut favours small pieces: without a core a "
                         "small piece could be cut down to a sliver; higher lets the cut reach weak material deeper "
                         "in the pieces and shrink the network more)")
    search_rounds: int = integer(1, 1, 4, "searches in all, each from the last one's surface while it lowers the "
                                 "functional: a crack may then travel several bands, and the pieces' cores shrink "
                                 "with them (each round costs a search); one more runs by itself, up to 4, while "
                                 "the last one's cut lies against its band's limits on a quarter of its weight or "
                                 "more (a tilted weak sheet beyond the first search's cores)")
    keep_volume: float = number(0.5, 0.0, 1.0, "every piece keeps at least this share of its coarse volume: a "
                                "flow step moves no sheet further into a piece it would leave below it, and a "
                                "search's cut that would is made again with a price on the volume that piece "
                                "loses (the coarse animation moves each piece as a rigid body of its own mass; "
                                "fracture/refine/volumes.py); 0: no limit")
    polish_stages: int = integer(0, 0, 8, "after the search, the flow polishes its surface on this many stages of the "
                                 "coarse-to-fine schedule before the last one, on level 0 (0: level 0 alone, which "
                                 "keeps the thin weak layers the cut found, a brick wall's; 1: the surface also settles "
                                 "into broad valleys of psi, on the Jell-O and the clay a lower functional)")

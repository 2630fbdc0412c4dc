"""Time Section 5 on the built-in scenes: building the pieces and playing the animation back.

For each scene the refinement runs first (not timed) up to ``--triangles``
fracture triangles; then the imprint of B, the piece assembly and the
transfer are timed, and the per-frame positions (one sparse product per
frame) are timed over every frame. Prints a table; the playback goal is 60
frames per second or more for a 200K-triangle result.

Usage: python benchmarks/bench_animate.py [--scenes bunny wall ...] [--triangles N] [--frames T]
"""

from __future__ import annotations

import argparse
import time

from scenes import in_processes, refine, scene_with_fields

SCENES = ("bunny", "branch", "wall", "clay", "jello")


def run_scene(name: str, triangles: int, frames: int, out) -> None:
    from fracture.pieces.imprint import imprint_boundary
    from fracture.pieces.assembly import build_pieces
    from fracture.pieces.transfer import build_transfer

    cfg, cf, fs = scene_with_fields(name, [f"input.frames={frames}", f"refine.max_triangles={triangles}"])
    mesh, _ = refine(cfg, cf, fs)
    t0 = time.perf_counter()
    im = imprint_boundary(cf.exterior_V, cf.exterior_F, mesh)
    t1 = time.perf_counter()
    pieces = build_pieces(im, mesh, cf.n_components, lambda f: cf.exterior_component[im.origin[f]])
    t2 = time.perf_counter()
    tr = build_transfer(cf, pieces, mesh.tree_matrix())
    t3 = time.perf_counter()
    tr.positions(0)
    t4 = time.perf_counter()
    for t in range(tr.n_frames):
        tr.positions(t)
    per_frame = (time.perf_counter() - t4) / tr.n_frames
    out.put(dict(fracture=len(mesh.F), pieces=pieces.n_pieces, triangles=sum(len(f) for f in pieces.faces),
                 rows=tr.own.shape[0], nnz=tr.own.nnz + tr.shared.nnz, imprint=t1 - t0, assemble=t2 - t1,
                 transfer=t3 - t2, per_frame=per_frame))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=SCENES)
    ap.add_argument("--triangles", type=int, default=100_000, help="refined fracture triangles (refine.max_triangles)")
    ap.add_argument("--frames", type=int, default=60)
    args = ap.parse_args()
    print("| scene | fracture tris | pieces | piece tris | vertex copies | nonzeros | imprint s | assemble s "
          "| transfer s | ms per frame | frames per s |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for name, r in in_processes(run_scene, args.scenes, args.triangles, args.frames):
        print(f"| {name} | {r['fracture']} | {r['pieces']} | {r['triangles']} | {r['rows']} | {r['nnz']} "
              f"| {r['imprint']:.2f} | {r['assemble']:.2f} | {r['transfer']:.2f} | {1e3 * r['per_frame']:.2f} "
              f"| {1 / r['per_frame']:.0f} |", flush=True)


if __name__ == "__main__":
    from fracture.process import prepare_process

    prepare_process()
    main()

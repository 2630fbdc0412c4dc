"""The refinement's iterations as a run stores them, for the viewer (``refined/iterations*``).

Per iteration the surface's positions, triangles, psi and speed per vertex,
kept compact (float32, int32) and concatenated into four arrays of one
compressed ``refined/iterations.npz`` (fixed time stamps: the bytes depend on
the data only), with ``refined/iterations.json`` giving each iteration's
vertex and triangle offsets. Runs made before it have the four arrays as
``refined/iterations_{positions,faces,psi,speed}.npy``, which are read too.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from fracture.io import layout


class Snapshots:
    """Per-iteration positions, triangles, psi and speed, kept compact (float32, int32)."""

    def __init__(self):
        self.V, self.F, self.psi, self.speed = [], [], [], []

    def add(self, V: np.ndarray, F: np.ndarray, psi: np.ndarray, speed: np.ndarray) -> None:
        self.V.append(V.astype(np.float32))
        self.F.append(F.astype(np.int32))
        self.psi.append(psi.astype(np.float32))
        self.speed.append(speed.astype(np.float32))

    def save(self, ctx, stem: str = layout.ITERATIONS) -> None:
        """Write them through a run's context (``save_array``, ``save_json``)."""
        nv = np.cumsum([0] + [len(v) for v in self.V])
        nf = np.cumsum([0] + [len(f) for f in self.F])
        ctx.save_npz(f"{stem}.npz", {"positions": np.concatenate(self.V), "faces": np.concatenate(self.F),
                                     "psi": np.concatenate(self.psi), "speed": np.concatenate(self.speed)},
                     compress=True)
        ctx.save_json(f"{stem}.json", {"vertex_offsets": nv.tolist(), "face_offsets": nf.tolist(),
                                       "snapshots": len(self.V)})


def load_snapshots(run_dir, stem: str = layout.ITERATIONS) -> list[dict]:
    """The snapshots of a run: per iteration a dict of positions, faces, psi, speed."""
    base = Path(run_dir) / stem
    doing = "cannot read the refinement's iterations"
    with layout.reading(run_dir, f"{stem}.json", doing):
        meta = json.loads(base.with_suffix(".json").read_text())
    keys = ("positions", "faces", "psi", "speed")
    if base.with_suffix(".npz").is_file():
        with layout.reading(run_dir, f"{stem}.npz", doing), np.load(base.with_suffix(".npz")) as z:
            arrays = {k: z[k] for k in keys}
    else:
        arrays = {}
        for k in keys:
            with layout.reading(run_dir, f"{stem}_{k}.npy", doing):
                arrays[k] = np.load(f"{base}_{k}.npy")
    with layout.reading(run_dir, f"{stem}.json", doing):  # its offsets and count, against the arrays
        nv, nf, count = meta["vertex_offsets"], meta["face_offsets"], int(meta["snapshots"])
        if min(len(nv), len(nf)) <= count or nv[count] > len(arrays["positions"]) \
                or nf[count] > len(arrays["faces"]):
            raise ValueError(f"its offsets do not fit the arrays ({len(arrays['positions'])} positions, "
                             f"{len(arrays['faces'])} faces)")
    return [{"positions": arrays["positions"][nv[i]:nv[i + 1]], "faces": arrays["faces"][nf[i]:nf[i + 1]],
             "psi": arrays["psi"][nv[i]:nv[i + 1]], "speed": arrays["speed"][nv[i]:nv[i + 1]]}
            for i in range(count)]

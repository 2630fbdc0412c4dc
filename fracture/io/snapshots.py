"""The refinement's iterations as a run stores them, for the viewer (``refined/iterations*``).

Per iteration the surface's positions, triangles, psi and speed per vertex,
kept compact (float32, int32) and concatenated into four plain ``.npy``
arrays (no archive time stamps: the bytes depend on the data only), with
``refined/iterations.json`` giving each iteration's vertex and triangle
offsets.
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
        ctx.save_array(f"{stem}_positions.npy", np.concatenate(self.V))
        ctx.save_array(f"{stem}_faces.npy", np.concatenate(self.F))
        ctx.save_array(f"{stem}_psi.npy", np.concatenate(self.psi))
        ctx.save_array(f"{stem}_speed.npy", np.concatenate(self.speed))
        ctx.save_json(f"{stem}.json", {"vertex_offsets": nv.tolist(), "face_offsets": nf.tolist(),
                                       "snapshots": len(self.V)})


def load_snapshots(run_dir, stem: str = layout.ITERATIONS) -> list[dict]:
    """The snapshots of a run: per iteration a dict of positions, faces, psi, speed."""
    base = Path(run_dir) / stem
    meta = json.loads(base.with_suffix(".json").read_text())
    arrays = {k: np.load(f"{base}_{k}.npy") for k in ("positions", "faces", "psi", "speed")}
    nv, nf = meta["vertex_offsets"], meta["face_offsets"]
    return [{"positions": arrays["positions"][nv[i]:nv[i + 1]], "faces": arrays["faces"][nf[i]:nf[i + 1]],
             "psi": arrays["psi"][nv[i]:nv[i + 1]], "speed": arrays["speed"][nv[i]:nv[i + 1]]}
            for i in range(meta["snapshots"])]

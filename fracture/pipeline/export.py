"""``fracref export``: a finished run's animated pieces in another format.

Reads the run directory (``coarse/components.json`` for the piece names,
``pieces/piece_NNN.ply`` for their triangles and exterior flags,
``animation/transfer.npz`` for the frames, ``config.yaml`` for the frame
rate, ``manifest.json`` for the up axis and the input's frame numbers, frame rate and unit) and writes one
file. The run itself writes the USD file already
(``animate.usd``); this exports it again elsewhere, or for a run made without it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from fracture.errors import InputError
from fracture.io import layout

FORMATS = ("usd",)


def _need(run: Path, rel: str) -> Path:
    p = run / rel
    if not p.is_file():
        raise InputError(f"{run}: cannot export, {rel} is missing (is this a run directory whose animate "
                         f"stage finished? run: fracref run CONFIG)")
    return p


def _reading(run: Path, rel: str):
    return layout.reading(run, rel, "cannot export")


def export_run(run: str | Path, fmt: str = "usd", out: str | Path | None = None, force: bool = False) -> Path:
    """Write the run's pieces and animation as ``fmt``; returns the file written.

    ``out`` defaults to ``RUN/animation/pieces.usdc`` (the run's own file, written again from the same
    outputs); another file that exists is replaced only with ``force``.
    """
    from fracture.io.ply import read_ply
    from fracture.pieces.transfer import frame_points, load_transfer, rest_points
    from fracture.io.usd import run_usd_timing, write_pieces_usd

    run = Path(run)
    if fmt not in FORMATS:
        raise InputError(f"export: unknown format {fmt!r}; expected one of {', '.join(FORMATS)}")
    if not run.is_dir():
        raise InputError(f"{run}: not a run directory")
    layout.not_a_sweep(run, "export")
    with _reading(run, layout.COMPONENTS):
        names = [str(name) for name in json.loads(_need(run, layout.COMPONENTS).read_text())["names"]]
    with _reading(run, layout.TRANSFER):
        transfer = load_transfer(_need(run, layout.TRANSFER))
    n = len(transfer.offsets) - 1
    if n != len(names):
        raise InputError(f"{run}: coarse/components.json names {len(names)} pieces, animation/transfer.npz has {n}")
    faces, exterior = [], []
    for c in range(n):
        rel = layout.piece(c)
        with _reading(run, rel):
            V, F, _, face_data = read_ply(_need(run, rel))
        if len(V) != transfer.offsets[c + 1] - transfer.offsets[c] or "exterior" not in face_data:
            raise InputError(f"{run / rel}: does not match animation/transfer.npz ({len(V)} vertices, "
                             f"expected {transfer.offsets[c + 1] - transfer.offsets[c]}, with a face property exterior)")
        faces.append(F)
        exterior.append(np.asarray(face_data["exterior"]).astype(bool))
    with _reading(run, layout.MANIFEST):
        manifest = layout.manifest_object(json.loads(_need(run, layout.MANIFEST).read_text()), run / layout.MANIFEST)
        up = manifest.get("stats", {}).get("coarse", {}).get("up_axis", "z")
    with _reading(run, layout.CONFIG):
        timing = run_usd_timing(yaml.safe_load(_need(run, layout.CONFIG).read_text()), manifest)
    out = Path(out) if out is not None else run / layout.USD
    if out.suffix not in (".usd", ".usdc", ".usda"):
        raise InputError(f"export: {out}: a USD file name ends in .usd, .usdc or .usda")
    if not out.parent.is_dir():
        raise InputError(f"export: {out.parent} is not a directory")
    if out.exists() and not force and out.resolve() != (run / layout.USD).resolve():
        raise InputError(f"export: {out} exists; choose another --out or pass --force to replace it")
    return write_pieces_usd(out, names, faces, exterior, frame_points(transfer), rest=rest_points(transfer),
                            size=transfer.size, up_axis="Y" if up == "y" else "Z", **timing)

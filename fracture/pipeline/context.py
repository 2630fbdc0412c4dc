"""What a stage sees and hands on: the run context and the stage products."""

from __future__ import annotations

import json
import logging
import sys
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np
from tqdm.auto import tqdm

from fracture.io.atomic import png_bytes
from fracture.pipeline.schema import Config

log = logging.getLogger(__name__)

# zlib's level for the compressed .npz outputs (save_npz): its fastest
_DEFLATE_LEVEL = 1

if TYPE_CHECKING:
    from fields.build import FieldSet
    from fracture.coarse.surface import CoarseFracture
    from fracture.pieces.assembly import Pieces
    from fracture.pieces.transfer import Transfer
    from fracture.mesh.fracture_surface import FractureSurface


@dataclass
class Products:
    """The in-memory results one stage hands to the later ones (None: not made yet)."""

    coarse: CoarseFracture | None = None  # coarse: the coarse fracture animation (Sec. 4.1)
    exterior: tuple[np.ndarray, np.ndarray] | None = None  # coarse: B's vertices and triangles
    fields: FieldSet | None = None  # fields: zeta, the distances and the pyramids (Sec. 4.2, 4.3)
    refined: FractureSurface | None = None  # refine: the refined fracture surface (Sec. 4.3, 4.4)
    pieces: Pieces | None = None  # animate: the watertight pieces (Sec. 5)
    transfer: Transfer | None = None  # animate: the deformation transfer (Sec. 5)

    def made(self) -> dict[str, Any]:
        """The products made so far, by name."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}

    def update(self, values: Mapping[str, Any] | None = None, **more: Any) -> None:
        """Set products by name (from a cache entry, say); an unknown name is an error."""
        for name, value in {**(values or {}), **more}.items():
            if name not in self.__dataclass_fields__:
                raise KeyError(f"unknown stage product {name!r}")
            setattr(self, name, value)


@dataclass
class RunContext:
    """What a stage sees: the config, its output directory and earlier products."""

    config: Config
    dir: Path
    progress: bool = True
    products: Products = field(default_factory=lambda: Products())
    counts: dict[str, Any] = field(default_factory=dict)
    stats: dict[str, Any] = field(default_factory=dict)
    files: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    # called as listener(event, data) by stages that report as they go (the viewer's re-run)
    listener: Any = None
    # the stage cache (fracture.pipeline.cache.StageCache) or None, and the keys of the stages run so far
    cache: Any = None
    keys: dict[str, str] = field(default_factory=dict)
    # an executor that writes the save_* files beside the stages (the runner's), and what it was given:
    # a file saved so is whole once the run waits for these (before its manifest), not on return
    writer: Any = None
    pending: list = field(default_factory=list)

    def tell(self, event: str, **data) -> None:
        if self.listener is not None:
            self.listener(event, data)

    def path(self, rel: str) -> Path:
        """Absolute path of an output file, recorded for the manifest."""
        p = self.dir / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        if rel not in self.files:
            self.files.append(rel)
        return p

    def _write(self, write, *args) -> None:
        """``write(*args)`` now, or by :attr:`writer` (the arguments are the caller's no more)."""
        if self.writer is None:
            write(*args)
        else:
            self.pending.append(self.writer.submit(write, *args))

    def wait_for_files(self) -> None:
        """Wait until every file saved so far is written (raises what a write raised)."""
        pending, self.pending = self.pending, []
        for done in pending:
            done.result()

    def save_array(self, rel: str, array: np.ndarray) -> None:
        """A ``.npy`` file (byte-identical for identical arrays)."""
        self._write(_write_npy, self.path(rel), np.array(array, order="C", copy=True))

    def save_npz(self, rel: str, arrays: dict[str, np.ndarray], compress: bool = False) -> None:
        """An ``.npz`` (deflated with ``compress``) with fixed member timestamps (byte-identical for identical
        arrays)."""
        import io
        import zipfile

        out = io.BytesIO()
        with zipfile.ZipFile(out, "w") as z:
            for name, a in arrays.items():
                buf = io.BytesIO()
                np.save(buf, np.ascontiguousarray(a), allow_pickle=False)
                info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
                info.compress_type = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
                # on the example's tree 0.017 s against 0.028 s at the default level, the file 2 % larger
                z.writestr(info, buf.getvalue(), compresslevel=_DEFLATE_LEVEL if compress else None)
        self._write(Path.write_bytes, self.path(rel), out.getvalue())

    def save_json(self, rel: str, data: Any) -> None:
        self._write(Path.write_bytes, self.path(rel),
                    (json.dumps(data, indent=2, sort_keys=True) + "\n").encode("utf-8"))

    def save_png(self, rel: str, image: np.ndarray) -> None:
        self._write(_write_png, self.path(rel), np.array(image, copy=True))

    def bar(self, total: int, desc: str):
        """A progress bar (silent when progress is off); it stays on screen when done."""
        return tqdm(total=total, desc=desc, disable=not self.progress, leave=True, file=sys.stderr)

    def say(self, text: str) -> None:
        """A line for the user among the progress bars (silent when progress is off), and on the log."""
        log.info("%s", text)
        if self.progress:
            tqdm.write(text, file=sys.stderr)


def _write_npy(path: Path, array: np.ndarray) -> None:
    with open(path, "wb") as f:
        np.save(f, array, allow_pickle=False)


def _write_png(path: Path, image: np.ndarray) -> None:
    path.write_bytes(png_bytes(image))

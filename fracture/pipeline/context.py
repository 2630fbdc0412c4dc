"""What a stage sees and hands on: the run context and the stage products."""

from __future__ import annotations

import json
import logging
import sys
from dataclasses import dataclass, field, fields
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np
from tqdm.auto import tqdm

from fracture.io.atomic import png_bytes
from fracture.pipeline.typed import Config, typed_config

log = logging.getLogger(__name__)

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

    cfg: dict
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

    @cached_property
    def config(self) -> Config:
        """The config as typed records (:func:`~fracture.pipeline.typed.typed_config`), made once per run."""
        return typed_config(self.cfg)

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

    def save_array(self, rel: str, array: np.ndarray) -> None:
        """A ``.npy`` file (byte-identical for identical arrays)."""
        with open(self.path(rel), "wb") as f:
            np.save(f, np.ascontiguousarray(array), allow_pickle=False)

    def save_npz(self, rel: str, arrays: dict[str, np.ndarray]) -> None:
        """An uncompressed ``.npz`` with fixed member timestamps (byte-identical for identical arrays)."""
        import io
        import zipfile

        with zipfile.ZipFile(self.path(rel), "w", zipfile.ZIP_STORED) as z:
            for name, a in arrays.items():
                buf = io.BytesIO()
                np.save(buf, np.ascontiguousarray(a), allow_pickle=False)
                z.writestr(zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0)), buf.getvalue())

    def save_json(self, rel: str, data: Any) -> None:
        self.path(rel).write_text(json.dumps(data, indent=2, sort_keys=True) + "\n", encoding="utf-8")

    def save_png(self, rel: str, image: np.ndarray) -> None:
        self.path(rel).write_bytes(png_bytes(image))

    def bar(self, total: int, desc: str):
        """A progress bar (silent when progress is off); it stays on screen when done."""
        return tqdm(total=total, desc=desc, disable=not self.progress, leave=True, file=sys.stderr)

    def say(self, text: str) -> None:
        """A line for the user among the progress bars (silent when progress is off), and on the log."""
        log.info("%s", text)
        if self.progress:
            tqdm.write(text, file=sys.stderr)

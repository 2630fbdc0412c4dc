"""Writing outputs so that a failure never leaves something that looks complete.

Single files go to a temporary sibling and are renamed over the target
(``os.replace`` is atomic on one file system). Run directories are built in a
hidden staging directory next to their final place and renamed into place only
when every stage has succeeded; an existing run is swapped out only with
``force``, and removed only after the new one is in place.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def png_bytes(image) -> bytes:
    """An ``(h, w, 3)`` uint8 image encoded as PNG (imageio), for :func:`atomic_write_bytes`."""
    import imageio.v3 as iio
    import numpy as np

    return iio.imwrite("<bytes>", np.ascontiguousarray(image), extension=".png")


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600; give the usual file mode
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


class RunDirectoryExists(FileExistsError):
    """The run directory exists and ``force`` was not given."""


def check_run_directory(out: Path, force: bool) -> None:
    """Refuse an existing, non-empty target unless ``force``."""
    if out.exists() and not force:
        if out.is_dir() and not any(out.iterdir()):
            return
        raise RunDirectoryExists(f"{out}: run directory exists; choose another --out or pass --force to replace it")
    if out.exists() and not out.is_dir():
        raise RunDirectoryExists(f"{out}: exists and is not a directory")


@contextlib.contextmanager
def staged_directory(out: str | Path, force: bool = False) -> Iterator[Path]:
    """Yield a fresh staging directory that becomes ``out`` on success.

    On any exception (including ``KeyboardInterrupt``) the staging directory
    is deleted and ``out`` is left exactly as it was.
    """
    out = Path(out).absolute()
    check_run_directory(out, force)
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    os.chmod(staging, 0o777 & ~_umask())  # mkdtemp creates 0700; give the usual directory mode
    try:
        yield staging
        check_run_directory(out, force)  # something may have appeared meanwhile
        old = None
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
            old.rmdir()
            os.replace(out, old)
        os.replace(staging, out)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise

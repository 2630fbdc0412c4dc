"""Writing outputs so that a failure never leaves something that looks complete.

Single files go to a temporary sibling and are renamed over the target
(``os.replace`` is atomic on one file system). Run directories are built in a
hidden staging directory next to their final place and renamed into place only
when every stage has succeeded; an existing run is swapped out only with
``force``, and removed only after the new one is in place.
"""

from __future__ import annotations

import contextlib
import glob
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from fracture.io import layout


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
    """The run directory exists and ``force`` was not given (or it is not a run, which ``force`` never replaces)."""


class OutputError(Exception):
    """A run directory could not be written (a path component is a file, the disk is full, no permission)."""


RUN_MARKER = layout.MANIFEST


def check_run_directory(out: Path, force: bool, marker: str = RUN_MARKER) -> None:
    """Refuse an existing, non-empty target unless ``force`` is given and it is an earlier run (holds ``marker``)."""
    blocked = next((p for p in out.parents if p.exists() and not p.is_dir()), None)
    if blocked is not None:
        raise RunDirectoryExists(f"{out}: {blocked} is a file, not a directory; choose another --out")
    if not out.exists():
        return
    if not out.is_dir():
        raise RunDirectoryExists(f"{out}: exists and is not a directory; choose another --out")
    if not any(out.iterdir()):
        return
    if not force:
        raise RunDirectoryExists(f"{out}: run directory exists; choose another --out or pass --force to replace it")
    if not (out / marker).is_file():
        raise RunDirectoryExists(f"{out}: is not a run directory (it has no {marker}) and is not empty; --force "
                                 "replaces only an earlier run: choose another --out")


def process_alive(pid: int) -> bool:
    """Whether the process ``pid`` still runs (a staging directory named after it is still in use)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def left_by_dead_writers(folder: Path, head: str, tail: str = "") -> list[Path]:
    """The entries ``HEAD PID REST TAIL`` of ``folder`` (``PID`` digits, up to a ``-`` or ``TAIL``) whose
    process ``PID`` is gone: what a killed writer left."""
    stale = []
    for p in sorted(folder.glob(f"{glob.escape(head)}*{glob.escape(tail)}")):
        pid = p.name[len(head):len(p.name) - len(tail)].split("-")[0]
        if pid.isdigit() and not process_alive(int(pid)):
            stale.append(p)
    return stale


def _stale(out: Path, kind: str) -> list[Path]:
    """The directories ``.NAME.KIND-PID-XXXX`` beside ``out`` whose process ``PID`` is gone."""
    return [p for p in left_by_dead_writers(out.parent, f".{out.name}.{kind}-") if p.is_dir()]


def _remove(p: Path) -> None:
    """Delete the folder ``p``, or the link ``p`` (an ``--out`` that was a link to a run: the run it names
    stays), leaving what cannot be deleted."""
    if p.is_symlink():
        with contextlib.suppress(OSError):
            p.unlink()
    else:
        shutil.rmtree(p, ignore_errors=True)


def remove_stale_staging(out: Path) -> list[Path]:
    """Remove what killed runs into ``out`` left beside it; returns the removed directories.

    A run is staged in ``.NAME.partial-PID-XXXX`` and, when it replaces an
    earlier run, moves that one to ``.NAME.old-PID-XXXX`` just before it
    takes its place, and deletes it after. Those of a process that still
    runs are left alone. A run killed between the two moves left no run at
    ``out``: its old one is moved back there (the earlier run, whole), and
    the others are deleted.
    """
    removed = []
    for p in _stale(out, "old"):
        if not out.exists():
            os.replace(p, out)
            continue
        _remove(p)
        removed.append(p)
    for p in _stale(out, "partial"):
        shutil.rmtree(p, ignore_errors=True)
        removed.append(p)
    return removed


@contextlib.contextmanager
def staged_directory(out: str | Path, force: bool = False, marker: str = RUN_MARKER) -> Iterator[Path]:
    """Yield a fresh staging directory that becomes ``out`` on success.

    On any exception (including ``KeyboardInterrupt``) the staging directory
    is deleted and ``out`` is left exactly as it was; one while the run it
    replaced is deleted, after the new one took its place, says so by its
    ``run_in_place`` (the new run's directory). An ``OSError`` while
    making or filling it (disk full, a file in the way) becomes an
    :class:`OutputError` that says so in one line.
    """
    out = Path(out).absolute()
    with contextlib.suppress(OSError):  # first: a run killed between its two moves gets its earlier run back
        remove_stale_staging(out)  # (a folder that cannot be read or written is said below)
    check_run_directory(out, force, marker)
    staging = old = None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-{os.getpid()}-", dir=out.parent))
        os.chmod(staging, 0o777 & ~_umask())  # mkdtemp creates 0700; give the usual directory mode
        yield staging
        check_run_directory(out, force, marker)  # something may have appeared meanwhile
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-{os.getpid()}-", dir=out.parent))
            old.rmdir()
            os.replace(out, old)
        os.replace(staging, out)
        staging = None  # the run is in place
    except BaseException as exc:
        if old is not None and not out.exists():  # stopped between the two moves: the earlier run goes back
            os.replace(old, out)
        if staging is not None:
            shutil.rmtree(staging, ignore_errors=True)
        if (not isinstance(exc, OSError) or isinstance(exc, RunDirectoryExists)
                or (exc.filename is not None and not str(exc.filename).startswith(str(out.parent)))):
            raise  # not a failure to write the run directory (an input file, say, or Ctrl-C)
        what = f"{exc.filename}: {exc.strerror}" if exc.filename is not None else str(exc)
        with contextlib.suppress(OSError):
            what += f"; {shutil.disk_usage(out.parent).free / 2 ** 20:.1f} MB free there"
        raise OutputError(f"{out}: cannot write the run ({what}); nothing was written and an earlier run there "
                          "is untouched") from None
    if old is not None:
        try:
            _remove(old)
        except BaseException as exc:  # Ctrl-C while the replaced run goes: this one is whole and in place (what
            exc.run_in_place = out  # is left of the other goes with the next run there: remove_stale_staging)
            raise

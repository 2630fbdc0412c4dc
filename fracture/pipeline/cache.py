"""A cache of stage results, so that a run redoes only the stages whose inputs changed.

A stage's result (the files it wrote, the products it hands to later stages,
its counts, statistics and notes) is stored under a key: the SHA-256 of

* the stage's name and the config sections it reads (:data:`STAGE_READS`),
  with the *content* of every file or folder those sections name;
* the key of the stage before it (so a change upstream invalidates
  everything downstream);
* the code: every source file of the ``fields`` and ``fracture`` packages and
  the versions of the numerical libraries.

A run whose coarse input is unchanged therefore reuses the coarse stage; one
with only ``psi`` changed reuses the coarse stage, inside the fields stage
the strength field and the distances, and inside the refine stage the global
search's band (:meth:`StageCache.value`). A reused
result is byte-identical to a recomputed one: its files are copies and its
products the pickled objects the stage made.

Entries are directories ``ROOT/<stage>/<key>/`` holding ``files/`` (the
stage's outputs at their run-relative paths), ``products.pkl`` and
``meta.json``. An entry is written into a hidden temporary directory in ROOT
and renamed into place whole, so it is complete or absent, whatever kills a
run and however many runs share the cache (the first to finish wins; the
others discard theirs). Reading touches ``meta.json``; when the cache grows
past its size, the entries read longest ago are removed. A reader that loses
an entry to another process's clean-up simply runs the stage.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import pickle
import shutil
import tempfile
import time
from dataclasses import dataclass
from functools import lru_cache
from importlib import metadata
from pathlib import Path
from typing import Any

from fracture.io.atomic import process_alive
from fracture.pipeline.schema import Config

# The config sections each stage reads (its result depends on nothing else but the stage before it).
STAGE_READS = {
    "coarse": ("input", "seed"),
    "fields": ("grid", "strength", "stress", "psi", "pyramid", "seed", "preview"),
    "refine": ("refine", "seed"),
    "animate": ("animate", "seed"),
}
# The distributions whose versions are part of every key (their numbers are in the results).
_LIBRARIES = ("numpy", "scipy", "numba", "pymeshlab", "libigl", "noise", "usd-core", "plyfile", "manifold3d")
DEFAULT_MAX_GB = 5.0


def default_root() -> Path:
    """``$FRACREF_CACHE_DIR``, else ``$XDG_CACHE_HOME/fracref``, else ``~/.cache/fracref``."""
    if os.environ.get("FRACREF_CACHE_DIR"):
        return Path(os.environ["FRACREF_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "fracref"


def default_max_bytes() -> int:
    """``$FRACREF_CACHE_MAX_GB`` (default 5) in bytes; an InputError when it is not a number of gigabytes."""
    from fracture.errors import InputError

    text = os.environ.get("FRACREF_CACHE_MAX_GB", str(DEFAULT_MAX_GB))
    try:
        gb = float(text)
    except ValueError:
        gb = float("nan")
    if not 0.0 <= gb < float("inf"):
        raise InputError(f"FRACREF_CACHE_MAX_GB={text!r}: expected the stage cache's size in gigabytes, a number "
                         f">= 0 (default {DEFAULT_MAX_GB:g})")
    return int(gb * 1e9)


def source_files() -> tuple[Path, list[Path]]:
    """The project's root and the pipeline's source files (of ``fields`` and ``fracture``), sorted."""
    root = Path(__file__).resolve().parents[2]  # fracture/pipeline/cache.py
    files = [path for package in ("fields", "fracture") for path in sorted((root / package).rglob("*.py"))]
    if not files:  # a key without the code would serve results of any earlier version
        raise RuntimeError(f"no pipeline sources under {root}")
    return root, files


@lru_cache(maxsize=1)
def code_version() -> str:
    """A digest of the pipeline's source files and the numerical libraries' versions."""
    h = hashlib.sha256()
    root, files = source_files()
    for path in files:
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    for name in _LIBRARIES:
        with contextlib.suppress(metadata.PackageNotFoundError):
            h.update(f"{name}=={metadata.version(name)}".encode())
    return h.hexdigest()


def _digest_path(h, path: Path) -> None:
    """Fold a file's content, or a folder's names and contents, into ``h``."""
    if path.is_file():
        with open(path, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
    else:
        for p in sorted(path.rglob("*")):
            if p.is_file():
                h.update(str(p.relative_to(path)).encode())
                _digest_path(h, p)


def _canonical(value: Any, h) -> Any:
    """``value`` as JSON-able data; a string naming an existing file or folder also folds its content into ``h``."""
    if isinstance(value, dict):
        return {str(k): _canonical(v, h) for k, v in sorted(value.items())}
    if isinstance(value, (list, tuple)):
        return [_canonical(v, h) for v in value]
    if isinstance(value, str) and os.path.isabs(value) and os.path.exists(value):
        _digest_path(h, Path(value))
    return value


def digest(*parts: Any) -> str:
    """The SHA-256 of JSON-able parts, with the content of the files and folders they name."""
    h = hashlib.sha256()
    data = _canonical(list(parts), h)
    h.update(json.dumps(data, sort_keys=True, default=str).encode())
    return h.hexdigest()


def stage_key(name: str, cfg: Config, previous: str) -> str:
    """The key of stage ``name`` of a run of ``cfg`` after a stage keyed ``previous`` (module notes)."""
    tree = cfg.tree()
    return digest(name, {k: tree[k] for k in STAGE_READS[name]}, previous, code_version())


@dataclass
class Entry:
    """A stored stage result."""

    path: Path
    meta: dict

    @property
    def files(self) -> list[str]:
        return list(self.meta["files"])

    def products(self) -> dict:
        with open(self.path / "products.pkl", "rb") as f:
            return pickle.load(f)


class StageCache:
    """Stage results by key under ``root``, at most about ``max_bytes`` in all (module notes)."""

    def __init__(self, root: str | Path | None = None, max_bytes: int | None = None):
        self.root = Path(root) if root is not None else default_root()
        self.max_bytes = default_max_bytes() if max_bytes is None else int(max_bytes)

    def _where(self, stage: str, key: str) -> Path:
        return self.root / stage / key

    def load(self, stage: str, key: str) -> Entry | None:
        """The entry of ``stage`` under ``key``, or None."""
        path = self._where(stage, key)
        try:
            meta = json.loads((path / "meta.json").read_text())
            os.utime(path / "meta.json")  # read now: kept longest by the clean-up
        except (OSError, ValueError):
            return None
        return Entry(path, meta)

    def restore(self, entry: Entry, target: Path) -> dict | None:
        """Copy an entry's files under ``target`` and return its products; None when the entry vanished
        meanwhile (another process's clean-up), in which case the caller runs the stage."""
        try:
            for rel in entry.files:
                dst = target / rel
                dst.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(entry.path / "files" / rel, dst)
            return entry.products()
        except (OSError, EOFError, pickle.UnpicklingError):
            return None

    def store(self, stage: str, key: str, source: Path, files: list[str], products: dict, meta: dict) -> Path | None:
        """Store a stage's result: ``files`` (relative to ``source``), its ``products`` and ``meta``; returns
        the entry's path, or None when the cache cannot be written (the run goes on without it)."""
        final = self._where(stage, key)
        if final.exists():
            return final
        tmp = None
        try:
            final.parent.mkdir(parents=True, exist_ok=True)
            tmp = Path(tempfile.mkdtemp(prefix=f".{key[:12]}.partial-{os.getpid()}-", dir=final.parent))
            for rel in files:
                dst = tmp / "files" / rel
                dst.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(source / rel, dst)
            with open(tmp / "products.pkl", "wb") as f:
                pickle.dump(products, f, protocol=pickle.HIGHEST_PROTOCOL)
            (tmp / "meta.json").write_text(json.dumps({**meta, "files": files, "stage": stage, "key": key,
                                                       "stored": time.time()}, indent=1, default=str))
            os.rename(tmp, final)  # atomic; fails if another run stored it first
            tmp = None
        except OSError:
            return final if final.exists() else None
        finally:
            if tmp is not None:
                shutil.rmtree(tmp, ignore_errors=True)
        return final

    def value(self, name: str, key: str) -> Any:
        """A value kept under ``key`` (:meth:`keep`; a part of a stage, e.g. the strength field), or None."""
        entry = self.load(name, key)
        if entry is None:
            return None
        with contextlib.suppress(OSError, EOFError, pickle.UnpicklingError, KeyError):
            return entry.products()["value"]
        return None

    def keep(self, name: str, key: str, value: Any) -> None:
        """Keep ``value`` under ``key`` for :meth:`value`."""
        self.store(name, key, self.root, [], {"value": value}, {})

    def entries(self) -> list[Path]:
        return [p for p in self.root.glob("*/*") if p.is_dir() and not p.name.startswith(".")]

    def size(self) -> int:
        return sum(f.stat().st_size for p in self.entries() for f in p.rglob("*") if f.is_file())

    def trim(self) -> list[Path]:
        """Remove the entries read longest ago until the cache holds at most ``max_bytes``; returns them.
        Temporary directories of killed runs (their process gone) go too. A run calls this once, at its end
        (it walks every entry)."""
        removed = []
        for tmp in [*self.root.glob("*/.*.partial-*"), *self.root.glob("*/.*.gone-*")]:
            pid = tmp.name.split(".partial-" if ".partial-" in tmp.name else ".gone-")[1].split("-")[0]
            if pid.isdigit() and not process_alive(int(pid)):
                shutil.rmtree(tmp, ignore_errors=True)
        sized = []
        for p in self.entries():
            with contextlib.suppress(OSError):
                used = (p / "meta.json").stat().st_mtime
                sized.append((used, sum(f.stat().st_size for f in p.rglob("*") if f.is_file()), p))
        total = sum(s for _, s, _ in sized)
        for _, s, p in sorted(sized, key=lambda t: t[0]):
            if total <= self.max_bytes:
                break
            doomed = p.parent / f".{p.name[:12]}.gone-{os.getpid()}-{time.monotonic_ns()}"
            with contextlib.suppress(OSError):
                os.rename(p, doomed)  # out of sight first: no reader finds half an entry
                shutil.rmtree(doomed, ignore_errors=True)
                removed.append(p)
                total -= s
        return removed

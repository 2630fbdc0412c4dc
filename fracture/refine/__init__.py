"""The refinement of the fracture surface (Sections 4.3, 4.4).

numba caches each compiled function beside its source and checks only that
file's time stamp, but the kernels here call each other across modules
(and those of :mod:`fracture.mesh`: flips and collisions use its hash grid):
a change in one module would leave stale machine code in the others' caches. :func:`clear_stale_numba_cache`
clears the cache when the package's sources differ from those it was compiled
from; programs call it once (:func:`fracture.process.prepare_process`), importing
the package does not.
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path


def _compiled_packages() -> list[Path]:
    """The packages whose numba kernels call each other: the refinement's and the mesh queries'."""
    here = Path(__file__).parent
    return [here, here.parent / "mesh"]


def clear_stale_numba_cache(packages: Path | list[Path] | None = None) -> bool:
    """Delete numba's cache files in every ``package/__pycache__`` (default: the refinement's and the
    mesh queries', whose kernels call each other) unless they were made from the current sources of
    all their ``*.py`` modules that use numba; returns whether anything was deleted."""
    packages = _compiled_packages() if packages is None else [packages] if isinstance(packages, Path) else packages
    sources = (p.read_bytes() for package in packages for p in sorted(package.glob("*.py")))
    digest = hashlib.sha1(b"".join(s for s in sources if b"import numba" in s)).hexdigest()
    stamps = [package / "__pycache__" / "numba-sources.sha1" for package in packages]
    try:
        if all(stamp.read_text() == digest for stamp in stamps):
            return False
    except OSError:
        pass
    stale = []
    try:
        for package, stamp in zip(packages, stamps):
            cache = package / "__pycache__"
            found = list(cache.glob("*.nb[ic]"))
            for f in found:
                f.unlink(missing_ok=True)
            stale += found
            cache.mkdir(exist_ok=True)
            tmp = stamp.with_suffix(".tmp")
            tmp.write_text(digest)
            tmp.replace(stamp)
    except OSError:  # a read-only install: numba caches elsewhere or not at all
        return False
    return bool(stale)


def kernels_cached(package: Path | None = None) -> bool:
    """Whether numba's cache holds the compiled (not inlined) functions of ``package`` (default: the
    refinement's and the mesh queries', compiled together), i.e. whether a run starts at once rather
    than after a one-off compilation. A run compiles only what it calls, so most of them (not every
    one) is enough."""
    packages = _compiled_packages() if package is None else [package]
    want, have = set(), set()
    for package in packages:
        want |= _compiled_names(package)
        have |= {f"{package.name}.{f.name.split('-')[0]}" for f in (package / "__pycache__").glob("*.nbi")}
    return len(want & have) >= 0.5 * len(want)


def _compiled_names(package: Path) -> set[str]:
    """``package.module.function`` of the functions numba caches in ``package`` (not the inlined ones)."""
    want = set()
    for p in package.glob("*.py"):
        for m in re.finditer(r"@numba\.njit\(([^)]*)\)\s*\ndef (\w+)", p.read_text(encoding="utf-8")):
            if "cache=True" in m.group(1) and "inline" not in m.group(1):
                want.add(f"{package.name}.{p.stem}.{m.group(2)}")
    return want

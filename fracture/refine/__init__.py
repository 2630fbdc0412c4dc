"""The refinement of the fracture surface (Sections 4.3, 4.4).

numba caches each compiled function beside its source and checks only that
file's time stamp, but the kernels here call each other across modules
(flips and collisions use the hash grid): a change in one module would leave
stale machine code in the others' caches. :func:`clear_stale_numba_cache`
clears the cache when the package's sources differ from those it was compiled
from; programs call it once (:func:`fracture.process.prepare_process`), importing
the package does not.
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path


def clear_stale_numba_cache(package: Path | None = None) -> bool:
    """Delete numba's cache files in ``package/__pycache__`` (default: this package's) unless they were
    made from the current sources of the ``package/*.py`` modules that use numba; returns whether
    anything was deleted."""
    package = package or Path(__file__).parent
    sources = (p.read_bytes() for p in sorted(package.glob("*.py")))
    digest = hashlib.sha1(b"".join(s for s in sources if b"import numba" in s)).hexdigest()
    cache = package / "__pycache__"
    stamp = cache / "numba-sources.sha1"
    try:
        if stamp.read_text() == digest:
            return False
    except OSError:
        pass
    try:
        stale = list(cache.glob("*.nb[ic]"))
        for f in stale:
            f.unlink(missing_ok=True)
        cache.mkdir(exist_ok=True)
        tmp = stamp.with_suffix(".tmp")
        tmp.write_text(digest)
        tmp.replace(stamp)
    except OSError:  # a read-only install: numba caches elsewhere or not at all
        return False
    return bool(stale)


def kernels_cached(package: Path | None = None) -> bool:
    """Whether numba's cache holds the compiled (not inlined) functions of ``package`` (default: this
    one), i.e. whether a run starts at once rather than after a one-off compilation. A run compiles
    only what it calls, so most of them (not every one) is enough."""
    package = package or Path(__file__).parent
    want = set()
    for p in package.glob("*.py"):
        for m in re.finditer(r"@numba\.njit\(([^)]*)\)\s*\ndef (\w+)", p.read_text(encoding="utf-8")):
            if "cache=True" in m.group(1) and "inline" not in m.group(1):
                want.add(f"{p.stem}.{m.group(2)}")
    have = {f.name.split("-")[0] for f in (package / "__pycache__").glob("*.nbi")}
    return len(want & have) >= 0.5 * len(want)

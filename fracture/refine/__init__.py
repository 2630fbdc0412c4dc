"""The refinement of the fracture surface (Sections 4.3, 4.4).

numba caches each compiled function beside its source and checks only that
file's time stamp, but the kernels call each other across modules and
packages (flips and collisions use :mod:`fracture.mesh`'s hash grid), and
freeze the module constants they read (the tolerances, copied from
:mod:`fracture.tolerances` as ``_TINY = tol.tiny``) into their machine
code: a change in another file would leave stale machine code behind.
:func:`clear_stale_numba_cache` clears the cache of every package with
compiled kernels (the fields', the mesh queries', the refinement's, the
pieces') when the sources they were compiled from differ from the current
ones: every module that uses numba and every module of the project it
imports, directly or not (the tolerances among them). Programs call it once
(:func:`fracture.process.prepare_process`); importing the package does not.
"""

from __future__ import annotations

import ast
import hashlib
import os
import re
from pathlib import Path

_ROOT = Path(__file__).resolve().parents[2]  # holds the fracture and fields packages
_TOP = ("fracture", "fields")


def _compiled_packages() -> list[Path]:
    """The packages with compiled kernels: the fields', the mesh queries', the refinement's and the pieces'."""
    return [_ROOT / "fields", _ROOT / "fracture" / "mesh", _ROOT / "fracture" / "refine", _ROOT / "fracture" / "pieces"]


def _module_path(name: str, root: Path) -> Path | None:
    """The file of project module ``name`` (dotted) under ``root``, or None if it is not one."""
    base = root.joinpath(*name.split("."))
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _imports(path: Path, root: Path) -> set[Path]:
    """The project modules that the module at ``path`` imports (absolute imports of the top packages)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_bytes())):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        for name in names:
            if name.split(".")[0] in _TOP:
                parts = name.split(".")
                for k in range(1, len(parts) + 1):  # a package's __init__ runs too
                    module = _module_path(".".join(parts[:k]), root)
                    if module is not None:
                        found.add(module)
    return found


def kernel_sources(packages: list[Path], root: Path = _ROOT) -> list[Path]:
    """The modules the compiled kernels of ``packages`` are made from: those that use numba and every
    project module (under ``root``) they import, directly or not (sorted)."""
    todo = [p for package in packages for p in sorted(package.glob("*.py")) if b"import numba" in p.read_bytes()]
    seen = set(todo)
    while todo:
        for module in _imports(todo.pop(), root) - seen:
            seen.add(module)
            todo.append(module)
    return sorted(seen)


def _digest(paths) -> str:
    """SHA-1 of the files' names (relative to the project's root where they are under it) and contents."""
    digest = hashlib.sha1()
    for path in paths:
        name = path.relative_to(_ROOT).as_posix() if path.is_relative_to(_ROOT) else path.name
        digest.update(name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def _tree_digest(packages: list[Path]) -> str:
    """The digest of every module of ``packages`` and of the top packages: a superset of their
    :func:`kernel_sources`, read in 12 ms where finding those parses every kernel module and what it
    imports (0.4 s, at every program's start)."""
    return _digest(sorted({p for folder in [*packages, *(_ROOT / top for top in _TOP)] for p in folder.rglob("*.py")}))


def clear_stale_numba_cache(packages: Path | list[Path] | None = None) -> bool:
    """Delete numba's cache files in every ``package/__pycache__`` (default: every package with compiled
    kernels, whose kernels call each other) unless they were made from the current content of
    :func:`kernel_sources`; returns whether anything was deleted.

    Each package's stamp (``numba-sources.sha1``) holds the kernel sources' digest and the digest of every
    module (:func:`_tree_digest`) when it was written: while no module changed, the sources are not looked
    for again; when one did, they are, and the caches go only if the kernels' own sources changed."""
    packages = _compiled_packages() if packages is None else [packages] if isinstance(packages, Path) else packages
    tree = _tree_digest(packages)
    stamps = [package / "__pycache__" / "numba-sources.sha1" for package in packages]
    try:
        kept = {tuple(stamp.read_text().split()) for stamp in stamps}  # (sources, tree) each
    except OSError:
        kept = set()
    known = kept.pop() if len(kept) == 1 else ()
    if known[1:] == (tree,):
        return False  # no module changed since the stamps were written
    digest = _digest(kernel_sources(packages))
    current = known[:1] == (digest,)  # a module changed, not the kernels' sources: the caches stay
    stale = []
    try:
        for package, stamp in zip(packages, stamps):
            cache = package / "__pycache__"
            if not current:
                found = list(cache.glob("*.nb[ic]"))
                for f in found:
                    f.unlink(missing_ok=True)
                stale += found
            cache.mkdir(exist_ok=True)
            tmp = stamp.with_suffix(f".{os.getpid()}.tmp")  # programs starting together (a sweep's) write their own
            tmp.write_text(f"{digest} {tree}")
            tmp.replace(stamp)
    except OSError:  # a read-only install: numba caches elsewhere or not at all
        return False
    return bool(stale)


def kernels_cached(package: Path | None = None) -> bool:
    """Whether numba's cache holds the compiled (not inlined) functions of ``package`` (default: the
    refinement's and the mesh queries', which the refine stage calls), i.e. whether a run starts at once
    rather than after a one-off compilation. A run compiles only what it calls, so most of them (not every
    one) is enough."""
    want, missing = _kernel_names(package)
    return len(missing) <= 0.5 * len(want)


def uncached_kernels(package: Path | None = None) -> list[str]:
    """``package.module.function`` of the compiled functions of ``package`` (default as
    :func:`kernels_cached`) that numba's cache does not hold."""
    return sorted(_kernel_names(package)[1])


def _kernel_names(package: Path | None) -> tuple[set[str], set[str]]:
    """The compiled functions of ``package`` (default as :func:`kernels_cached`), and those not cached."""
    packages = [_ROOT / "fracture" / "refine", _ROOT / "fracture" / "mesh"] if package is None else [package]
    want, have = set(), set()
    for package in packages:
        want |= _compiled_names(package)
        have |= {f"{package.name}.{f.name.split('-')[0]}" for f in (package / "__pycache__").glob("*.nbi")}
    return want, want - have


def _compiled_names(package: Path) -> set[str]:
    """``package.module.function`` of the functions numba caches in ``package`` (not the inlined ones)."""
    want = set()
    for p in package.glob("*.py"):
        for m in re.finditer(r"@numba\.njit\(([^)]*)\)\s*\ndef (\w+)", p.read_text(encoding="utf-8")):
            if "cache=True" in m.group(1) and "inline" not in m.group(1):
                want.add(f"{package.name}.{p.stem}.{m.group(2)}")
    return want

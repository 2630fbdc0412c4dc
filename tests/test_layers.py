"""The packages' layers: ``fields`` stands on its own, ``fracture`` on ``fields``, ``viewer`` on both."""

import ast
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

REPO = Path(__file__).resolve().parents[1]


def _modules_loaded_by(package: str) -> set[str]:
    """Top-level packages of this project in ``sys.modules`` after importing every module of ``package``."""
    code = f"""
import importlib, pkgutil, sys
import {package} as pkg
for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
    if not m.name.endswith("__main__"):
        importlib.import_module(m.name)
print(" ".join(sorted({{n.split(".")[0] for n in sys.modules}} & {{"fields", "fracture", "viewer"}})))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    return set(out.stdout.split())


@pytest.mark.parametrize("package, below", [("fields", {"fields"}), ("fracture", {"fields", "fracture"}),
                                            ("viewer", {"fields", "fracture", "viewer"})])
def test_a_package_imports_only_the_layers_below_it(package, below):
    assert _modules_loaded_by(package) == below


def _import_graph() -> tuple[list[str], set[tuple[str, str]]]:
    """The project's modules and the pairs (importer, imported), module-level and local imports alike."""
    paths = {}
    for root in ("fields", "fracture", "viewer", "fracref"):
        for p in (REPO / root).rglob("*.py"):
            name = ".".join(p.relative_to(REPO).with_suffix("").parts)
            paths[name.removesuffix(".__init__")] = p
    edges = set()
    for name, p in paths.items():
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module:
                targets = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            edges.update((name, t) for t in targets if t in paths and t != name)
    return sorted(paths), edges


def test_no_module_imports_itself_through_others():
    names, edges = _import_graph()
    index = {n: i for i, n in enumerate(names)}
    rows, cols = zip(*((index[a], index[b]) for a, b in edges))
    graph = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(names), len(names)))
    _, label = connected_components(graph, directed=True, connection="strong")
    circles = [[n for n, k in zip(names, label) if k == c] for c in np.unique(label) if (label == c).sum() > 1]
    assert circles == []


def _unit(module: str) -> str:
    """The subpackage (or top-level module) of ``fracture`` a module belongs to, else its package."""
    parts = module.split(".")
    return ".".join(parts[:2]) if parts[0] == "fracture" and len(parts) > 1 else parts[0]


def test_no_subpackage_imports_itself_through_others():
    """The subpackages of ``fracture`` (and its top-level modules) form layers too: errors and
    tolerances at the bottom, the IO below what uses it, the pipeline on top; no two import each other,
    directly or through others (local imports count)."""
    _, edges = _import_graph()
    units = sorted({_unit(n) for edge in edges for n in edge})
    index = {u: i for i, u in enumerate(units)}
    pairs = {(index[_unit(a)], index[_unit(b)]) for a, b in edges if _unit(a) != _unit(b)}
    rows, cols = zip(*pairs)
    graph = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(units), len(units)))
    _, label = connected_components(graph, directed=True, connection="strong")
    circles = [[u for u, k in zip(units, label) if k == c] for c in np.unique(label) if (label == c).sum() > 1]
    assert circles == [], [sorted((a, b) for a, b in edges if _unit(a) in circles[0] and _unit(b) in circles[0]
                                  and _unit(a) != _unit(b))]


def test_no_epsilon_is_typed_inline_in_an_expression():
    """Tolerances are named: in tol (fracture/tolerances.py, fields/tolerances.py), in view_tol
    (viewer/tolerances.py) or as a module constant with its reason; no expression of the code types a
    small number in scientific notation (declared ranges and defaults of parameters excepted)."""
    import re

    small = re.compile(r"(?<![\w.])\d+(\.\d+)?e-\d+")
    declared = [re.compile(p) for p in (
        r"^\s*[A-Z_][A-Z0-9_]*\s*(:[^=]*)?=",  # a module constant (its reason on the lines above)
        r"\b(lo|hi)=|\b(number|integer|vec3|int3)\(",  # a parameter's declared range or default
        r"\w+\s*(:\s*[\w\[\], |]+)?=\s*\d+(\.\d+)?e-\d+\s*[,)]",  # a keyword argument's default
    )]
    found = []
    for package in ("fracture", "fields", "viewer"):
        for path in sorted((REPO / package).rglob("*.py")):
            if path.name == "tolerances.py":
                continue
            in_doc = False
            for number, line in enumerate(path.read_text().splitlines(), 1):
                if line.count('"""') % 2:
                    in_doc = not in_doc
                    continue
                code = line.split("#", 1)[0]
                if in_doc or not small.search(code) or any(d.search(line) for d in declared):
                    continue
                found.append(f"{path.relative_to(REPO)}:{number}: {line.strip()}")
    assert not found, "epsilons typed inline:\n" + "\n".join(found)


def test_importing_the_packages_leaves_the_environment_alone():
    """The project's modules set nothing in ``os.environ`` when imported (the libraries they use are
    imported first: Open3D's own import sets OpenMP variables)."""
    code = """
import importlib, os, pkgutil
import igl, numba, numpy, open3d, pymeshlab, scipy
before = dict(os.environ)
for name in ("fields", "fracture", "viewer"):
    pkg = importlib.import_module(name)
    for m in pkgutil.walk_packages(pkg.__path__, name + "."):
        if not m.name.endswith("__main__"):
            importlib.import_module(m.name)
print(sorted(set(os.environ.items()) ^ set(before.items())))
"""
    env = {k: v for k, v in __import__("os").environ.items() if k not in ("DISPLAY", "EGL_PLATFORM")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "[]"

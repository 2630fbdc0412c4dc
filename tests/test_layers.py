"""The packages' layers: ``fields`` stands on its own, ``fracture`` on ``fields``, ``viewer`` on both."""

import subprocess
import sys

import pytest


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


@pytest.mark.parametrize("package, below", [("fields", {"fields"})])
def test_a_package_imports_only_the_layers_below_it(package, below):
    assert _modules_loaded_by(package) == below

"""The configs that ship with the package, found by name: the strength presets (``strength/bricks``) and
the experiments (``example``, ``bunny``, ...).

They are the repository's ``configs/`` folder, which the package holds as
``fracture/presets`` (a link in a checkout, the files themselves in a
wheel), so a config anywhere can start from one: ``defaults:
[strength/bricks]`` looks next to the config first, then here
(:func:`fracture.pipeline.config.load_config`). ``fracref presets`` lists
them with the first line of each file's header.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def root() -> Path:
    """The presets' folder."""
    return Path(str(resources.files("fracture") / "presets"))


def find(name: str) -> Path | None:
    """The preset ``name`` (``.yaml`` optional; ``strength/bricks``), or None."""
    base = root()
    target = base / (name if name.endswith((".yaml", ".yml")) else name + ".yaml")  # "bricks.old" is no "bricks"
    try:
        target.resolve().relative_to(base.resolve())  # a name, not a way out of the folder
    except ValueError:
        return None
    return target if target.is_file() else None


def names() -> list[str]:
    """Every preset's name, the experiments first, then the groups (``strength/...``)."""
    base = root()
    found = sorted(base.glob("*.yaml")) + sorted(base.glob("*/*.yaml"))
    return [p.relative_to(base).with_suffix("").as_posix() for p in found]


def summary(name: str) -> str:
    """The first sentence of a preset's header comment (its opening ``#`` lines)."""
    path = find(name)
    lines = []
    for line in path.read_text(encoding="utf-8").splitlines() if path is not None else []:
        if not line.startswith("#"):
            break
        lines.append(line.lstrip("#").strip())
    text = " ".join(lines)
    end = text.find(". ")
    return text if end < 0 else text[:end + 1]


__all__ = ["find", "names", "root", "summary"]

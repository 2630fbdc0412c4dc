"""Colour maps for field slices and colour bars.

Piecewise-linear in RGB between samples of the perceptually uniform
matplotlib maps (viridis, magma) and Moreland's diverging cool-warm map;
samples every 1/8 are within a few levels of 255 of the originals, which is
plenty for figures and avoids a plotting-library dependency.
"""

from __future__ import annotations

import numpy as np

_ANCHORS = {
    "viridis": ["#440154", "#472c7a", "#3b528b", "#2c728e", "#21918c", "#28ae80", "#5ec962", "#addc30", "#fde725"],
    "magma": ["#000004", "#1c1044", "#4f127b", "#812581", "#b5367a", "#e55064", "#fb8761", "#fec287", "#fcfdbf"],
    "coolwarm": ["#3b4cc0", "#6282ea", "#8db0fe", "#b8d0f9", "#dddcdc", "#f5c4ad", "#f49a7b", "#de604d", "#b40426"],
    "gray": ["#000000", "#ffffff"],
}

NAMES = tuple(_ANCHORS)


def _rgb(hex_colors: list[str]) -> np.ndarray:
    return np.array([[int(h[i : i + 2], 16) for i in (1, 3, 5)] for h in hex_colors], np.float64) / 255.0


def colormap(values: np.ndarray, name: str = "viridis", vmin: float | None = None, vmax: float | None = None) -> np.ndarray:
    """Map scalars to RGB.

    Parameters
    ----------
    values : (...) float
    name : str
        One of :data:`NAMES`.
    vmin, vmax : float, optional
        Range mapped to the ends of the map (default: the data range).

    Returns
    -------
    (..., 3) float in [0, 1]
    """
    if name not in _ANCHORS:
        raise ValueError(f"unknown colour map {name!r}, expected one of {', '.join(NAMES)}")
    values = np.asarray(values, np.float64)
    lo = float(np.nanmin(values)) if vmin is None else float(vmin)
    hi = float(np.nanmax(values)) if vmax is None else float(vmax)
    t = np.clip((values - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.zeros_like(values)
    anchors = _rgb(_ANCHORS[name])
    x = np.linspace(0.0, 1.0, len(anchors))
    return np.stack([np.interp(t, x, anchors[:, c]) for c in range(3)], axis=-1)


def srgb_to_linear(c) -> np.ndarray:
    """sRGB values in [0, 1] (as colour maps give them) in linear light (the IEC 61966-2-1 curve)."""
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c) -> np.ndarray:
    """Linear light in [0, 1] as sRGB values (the inverse of :func:`srgb_to_linear`)."""
    c = np.clip(np.asarray(c, np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    return np.round(np.clip(rgb, 0.0, 1.0) * 255.0).astype(np.uint8)


def colorbar(name: str = "viridis", length: int = 256, thickness: int = 16, vertical: bool = True) -> np.ndarray:
    """An RGB ``uint8`` colour bar image, low values at the bottom (or left)."""
    t = np.linspace(0.0, 1.0, length)
    rgb = to_uint8(colormap(t, name, 0.0, 1.0))
    if vertical:
        return np.repeat(rgb[::-1, None, :], thickness, axis=1)
    return np.repeat(rgb[None, :, :], thickness, axis=0)

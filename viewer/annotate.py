"""Colour bars and captions drawn onto rendered images (Pillow), for figures and video frames."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from fields.colormap import colorbar

INK = (30, 30, 30)


@lru_cache(maxsize=8)
def _font(size: int):
    for name in ("DejaVuSans.ttf", "LiberationSans-Regular.ttf", "Arial.ttf"):
        try:
            return ImageFont.truetype(name, size)
        except OSError:
            continue
    return ImageFont.load_default(size=size)


def _fmt(x: float) -> str:
    return f"{x:.3g}"


def with_colorbar(image: np.ndarray, cmap: str, value_range: tuple[float, float], label: str,
                  caption: str | None = None) -> np.ndarray:
    """``image`` with a vertical colour bar (``label`` above, the range's ends beside it) at the right edge."""
    h, w = image.shape[:2]
    size = max(12, h // 40)
    bar_h, bar_w = int(0.5 * h), max(10, w // 70)
    x0 = w - bar_w - 5 * size
    y0 = (h - bar_h) // 2
    out = image.copy()
    out[y0:y0 + bar_h, x0:x0 + bar_w] = colorbar(cmap, bar_h, bar_w)
    out[y0:y0 + bar_h, [x0 - 1, x0 + bar_w]] = INK
    out[[y0 - 1, y0 + bar_h], x0 - 1:x0 + bar_w + 1] = INK
    pil = Image.fromarray(out)
    d = ImageDraw.Draw(pil)
    f = _font(size)
    lo, hi = value_range
    d.text((x0 + bar_w + size // 2, y0), _fmt(hi), fill=INK, font=f, anchor="lt")
    d.text((x0 + bar_w + size // 2, y0 + bar_h), _fmt(lo), fill=INK, font=f, anchor="lb")
    d.text((x0 + bar_w // 2, y0 - size // 2), label, fill=INK, font=f, anchor="mb")
    if caption:
        d.text((size, h - size), caption, fill=INK, font=f, anchor="lb")
    return np.asarray(pil)


def caption(image: np.ndarray, text: str) -> np.ndarray:
    """``image`` with ``text`` at its lower left."""
    h = image.shape[0]
    size = max(12, h // 40)
    pil = Image.fromarray(image.copy())
    ImageDraw.Draw(pil).text((size, h - size), text, fill=INK, font=_font(size), anchor="lb")
    return np.asarray(pil)

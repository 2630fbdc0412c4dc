"""Figures around a rendered picture (Pillow): a colour bar with ticks and the field's name in a
strip at the right, a caption in a strip below, neither drawn over the picture.

A figure of ``width x height`` pixels is laid out first (:func:`layout`), the picture rendered at
the size it leaves, then :func:`compose` puts the pieces together. Pictures with an alpha channel
(transparent backgrounds) give figures with one; the strips are then transparent too.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from fields.colormap import colorbar, linear_to_srgb, srgb_to_linear
from viewer.tolerances import view_tol

INK = (30, 30, 30)
PAPER = (255, 255, 255)


@dataclass(frozen=True)
class Bar:
    """A colour bar: the colour map, the values at its ends and the name of what it shows."""

    cmap: str
    lo: float
    hi: float
    label: str


@dataclass(frozen=True)
class Layout:
    """Where the picture, the colour bar strip and the caption strip go in a figure."""

    width: int
    height: int
    bar_width: int  # 0: no colour bar
    caption_height: int  # 0: no caption
    text: int  # font size in pixels

    @property
    def picture(self) -> tuple[int, int]:
        """The picture's size (width, height)."""
        return self.width - self.bar_width, self.height - self.caption_height


def layout(width: int, height: int, bar: bool, caption: bool) -> Layout:
    """The figure's layout: the bar strip about a seventh of the width, the caption two lines of text."""
    text = max(12, min(height // 40, width // 45))
    bar_w = max(6 * text, width // 7) if bar else 0
    cap_h = int(2.0 * text) if caption else 0
    return Layout(width, height, bar_w, cap_h, text)


@lru_cache(maxsize=8)
def _font(size: int):
    for name in ("DejaVuSans.ttf", "LiberationSans-Regular.ttf", "Arial.ttf"):
        try:
            return ImageFont.truetype(name, size)
        except OSError:
            continue
    return ImageFont.load_default(size=size)


def nice_ticks(lo: float, hi: float, most: int = 6) -> np.ndarray:
    """Round values in ``[lo, hi]`` spaced by 1, 2 or 5 times a power of ten, at most ``most`` of them
    (the ends of the range are labelled separately when no tick falls near them)."""
    if not hi > lo:
        return np.array([lo])
    raw = (hi - lo) / max(most - 1, 1)
    mag = 10.0 ** np.floor(np.log10(raw))
    step = next(m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw)
    first = np.ceil(lo / step - view_tol.tick) * step
    ticks = np.arange(first, hi + view_tol.tick * step, step)
    return np.round(ticks / step) * step + 0.0  # no 0.30000000000000004, no -0.0


def tick_labels(ticks: np.ndarray) -> list[str]:
    """The ticks written with as many significant digits as tell them apart (at least three)."""
    t = np.asarray(ticks, np.float64)
    step = np.min(np.diff(t)) if len(t) > 1 else 0.0
    big = np.max(np.abs(t)) if len(t) else 0.0
    digits = 3 if step <= 0 or big <= 0 else max(3, int(np.ceil(np.log10(big / step))) + 1)
    if big >= 1:  # whole numbers written out (1000, not 1e+03)
        digits = max(digits, int(np.floor(np.log10(big))) + 1)
    return [f"{x:.{digits}g}" if x != 0 else "0" for x in t]


def _fit(draw: ImageDraw.ImageDraw, text: str, size: int, room: int) -> tuple[str, ImageFont.FreeTypeFont]:
    """``text`` in the largest font up to ``size`` that fits ``room`` pixels (shortened with an ellipsis at 10 px)."""
    for s in range(size, 9, -1):
        f = _font(s)
        if draw.textlength(text, font=f) <= room:
            return text, f
    f = _font(10)
    while text and draw.textlength(text + "...", font=f) > room:
        text = text[:-1]
    return text + "...", f


def compose(picture: np.ndarray, lay: Layout, bar: Bar | None = None, caption: str | None = None) -> np.ndarray:
    """The figure: ``picture`` (of ``lay.picture`` size, RGB or RGBA) at the upper left, the colour bar
    strip at its right and the caption strip below."""
    ph, pw = picture.shape[:2]
    if (pw, ph) != lay.picture:
        raise ValueError(f"picture of {pw}x{ph}, the layout leaves {lay.picture[0]}x{lay.picture[1]}")
    channels = picture.shape[2]
    paper = PAPER + ((0,) if channels == 4 else ())
    ink = INK + ((255,) if channels == 4 else ())
    out = np.empty((lay.height, lay.width, channels), np.uint8)
    out[:] = paper
    out[:ph, :pw] = picture
    pil = Image.fromarray(out)
    d = ImageDraw.Draw(pil)
    t = lay.text
    if bar is not None and lay.bar_width:
        bar_h, bar_w = int(0.6 * ph), max(10, lay.bar_width // 6)
        x0, y0 = pw + t, (ph - bar_h) // 2
        strip = colorbar(bar.cmap, bar_h, bar_w)  # high values at the top
        if channels == 4:
            strip = np.concatenate([strip, np.full(strip.shape[:2] + (1,), 255, np.uint8)], axis=2)
        pil.paste(Image.fromarray(strip), (x0, y0))
        d.rectangle([x0 - 1, y0 - 1, x0 + bar_w, y0 + bar_h], outline=ink)
        name, f = _fit(d, bar.label, t, lay.width - x0 - t // 2)
        d.text((x0, y0 - t), name, fill=ink, font=f, anchor="lb")
        f = _font(max(10, int(0.85 * t)))
        span = bar.hi - bar.lo
        ticks = nice_ticks(bar.lo, bar.hi)
        for v, text in zip(ticks, tick_labels(ticks)):
            y = y0 + bar_h - 1 - round((v - bar.lo) / span * (bar_h - 1)) if span > 0 else y0 + bar_h // 2
            d.line([x0 + bar_w, y, x0 + bar_w + t // 2, y], fill=ink, width=max(1, t // 12))
            d.text((x0 + bar_w + (2 * t) // 3, y), text, fill=ink, font=f, anchor="lm")
    if caption and lay.caption_height:
        text, f = _fit(d, caption, t, lay.width - 2 * t)
        d.text((t, ph + lay.caption_height // 2), text, fill=ink, font=f, anchor="lm")
    return np.asarray(pil)


def side_by_side(figures: list[np.ndarray]) -> np.ndarray:
    """Figures of one height next to each other."""
    return np.concatenate(figures, axis=1)


def over_white(image: np.ndarray) -> np.ndarray:
    """An RGBA figure composited on white (for a video); RGB as is."""
    if image.shape[2] == 3:
        return image
    a = image[..., 3:4].astype(np.float32) / 255.0
    return np.round(image[..., :3] * a + 255.0 * (1 - a)).astype(np.uint8)


def _block_mean(img: np.ndarray, k: int) -> np.ndarray:
    if k == 1:
        return img
    h, w, c = img.shape
    return img.reshape(h // k, k, w // k, k, c).mean(axis=(1, 3))


def finish(on_white: np.ndarray, on_black: np.ndarray | None = None, k: int = 1) -> np.ndarray:
    """A rendered picture made ``k`` times smaller (each pixel the mean of a k x k block: supersampling)
    and, given the same picture rendered on black, with its coverage as alpha (difference matting:
    one minus the two pictures' difference; the colour is the black one's divided by it).

    Both are done in linear light, where the renderer blends: in sRGB values a see-through surface's
    coverage and an edge's mean colour would come out wrong. RGB or RGBA uint8.
    """
    white = _block_mean(srgb_to_linear(np.asarray(on_white, np.float64) / 255.0), k)
    if on_black is None:
        return np.round(255.0 * linear_to_srgb(white)).astype(np.uint8)
    black = _block_mean(srgb_to_linear(np.asarray(on_black, np.float64) / 255.0), k)
    # the renderer's colour grading leaves white and black a unit or two off: within 1 % is clear or solid
    alpha = np.clip((0.99 - (white - black).max(axis=2, keepdims=True)) / 0.98, 0.0, 1.0)
    rgb = np.where(alpha > view_tol.opaque, black / np.maximum(alpha, view_tol.opaque), 0.0)
    return np.round(np.concatenate([255.0 * linear_to_srgb(rgb), 255.0 * alpha], axis=2)).astype(np.uint8)

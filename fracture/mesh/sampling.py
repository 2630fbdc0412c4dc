"""Points spread over a triangle surface with uniform density per area (the square-root trick: a
uniform point of a triangle from two uniform numbers)."""

from __future__ import annotations

import numpy as np


def uniform_barycentric(r1: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """Barycentric weights ``(n, 3)`` of uniform points of a triangle, from uniform numbers in [0, 1)."""
    s = np.sqrt(r1)
    return np.column_stack([1.0 - s, s * (1.0 - r2), s * r2])


def area_barycentric(area: np.ndarray, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``count`` points spread over triangles of areas ``area`` with uniform density per area: the triangle
    each lies on and its barycentric weights ``(count, 3)`` (the same points can then be put on the
    triangles moved anywhere)."""
    f = rng.choice(len(area), size=count, p=area / area.sum())
    return f, uniform_barycentric(rng.random(count), rng.random(count))


def area_samples(V: np.ndarray, F: np.ndarray, count: int, rng: np.random.Generator
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``count`` points ``(count, 3)`` spread over the surface with uniform density per area, and the
    triangle each lies on."""
    T = V[F]
    area = 0.5 * np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1)
    f, bary = area_barycentric(area, count, rng)
    return np.einsum("nk,nkc->nc", bary, T[f]), f

"""A small, deterministic low-resolution animator for the built-in scenes.

Not a simulator of fracture: the scenes prescribe when and how pieces let go.
Two kinds of motion, each a map from material points to positions per
component and frame, sampled on a lattice per component (the
:class:`~fracture.coarse.animation.CoarseAnimation` representation):

* :func:`rigid_bodies`: pieces under gravity with ground contact (restitution,
  Coulomb-like friction, spin damping on contact), integrated with small
  explicit steps; before its release frame every piece follows the object;
* :func:`fracture.coarse.animation.lattice_animation`: any smooth deformation
  field per component (twist, bending, elastic wobble), sampled on an
  ``n^3`` lattice.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.spatial import ConvexHull

from fracture.coarse.animation import rigid_fit
from fracture.tolerances import tol

GRAVITY = 9.81


def rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix about a unit axis (Rodrigues)."""
    axis = np.asarray(axis, np.float64)
    k = axis / max(np.linalg.norm(axis), tol.tiny)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def rigid_bodies(hulls: list[np.ndarray], frames: int, release: np.ndarray, kick: Callable[[int], tuple],
                 carrier: Callable[[int, np.ndarray], np.ndarray] | None = None, up: int = 1,
                 ground: float = 0.0, fps: float = 30.0, substeps: int = 20, restitution: float = 0.25,
                 friction: float = 0.4, spin_damping: float = 0.6) -> list[list[tuple[np.ndarray, np.ndarray]]]:
    """Rigid pieces released at given frames, then falling onto a ground plane.

    Parameters
    ----------
    hulls : list of (k, 3) float
        Material points of each piece; their convex hull touches the ground.
    frames : int
    release : (C,) int
        Frame from which each piece moves on its own (``frames``: never).
    kick : callable ``c -> (velocity (3,), angular velocity (3,))``
        Velocities a piece has when it is released, added to the carrier's.
    carrier : callable ``(t, X) -> x``, optional
        Rigid motion of the intact object before release (default: at rest).
        Must be rigid; the piece inherits its velocity at release.
    up : int
        Axis of gravity (pointing down along ``-up``).

    Returns
    -------
    list (per piece) of list (per frame) of ``(R, t)`` with ``x = R X + t``.
    """
    carrier = carrier or (lambda t, X: X)
    dt = 1.0 / fps / substeps
    g = np.zeros(3)
    g[up] = -GRAVITY
    out = []
    for c, H in enumerate(hulls):
        com = H.mean(axis=0)
        H = H[ConvexHull(H).vertices]  # a plane touches a body at its convex hull
        poses = []
        R, x, v, w = np.eye(3), com.copy(), np.zeros(3), np.zeros(3)
        for t in range(frames):
            if t <= release[c]:
                # follow the carrier (a rigid motion, recovered from the hull's points)
                P = carrier(t, H)
                R, x = _rigid_from_points(H, P, com)
                if t == release[c]:
                    Pn = carrier(t + 1, H) if t + 1 < frames else P
                    _, xn = _rigid_from_points(H, Pn, com)
                    v0, w0 = kick(c)
                    v, w = (xn - x) * fps + v0, np.asarray(w0, np.float64)
                poses.append((R, x - R @ com))
                continue
            for _ in range(substeps):
                v = v + dt * g
                x = x + dt * v
                R = rotation(w, np.linalg.norm(w) * dt) @ R if np.linalg.norm(w) > 0 else R
                low = ((H - com) @ R.T + x)[:, up].min()
                if low < ground:
                    x[up] += ground - low
                    if v[up] < 0:
                        v[up] = -restitution * v[up]
                        tangential = v.copy()
                        tangential[up] = 0.0
                        v -= friction * tangential
                        w *= spin_damping
            poses.append((R, x - R @ com))
        out.append(poses)
    return out


def _rigid_from_points(X: np.ndarray, Y: np.ndarray, com: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    R, t = rigid_fit(X, Y)
    return R, R @ com + t


def rigid_motion(poses: list[list[tuple[np.ndarray, np.ndarray]]]) -> Callable[[int, int, np.ndarray], np.ndarray]:
    """The motion ``(c, t, X) -> x`` of poses from :func:`rigid_bodies`."""
    def motion(c, t, X):
        R, s = poses[c][t]
        return X @ R.T + s
    return motion

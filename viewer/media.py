"""Image sizes and MP4 writing shared by the window's exports and the headless renders.

Kept apart from :mod:`viewer.render`, whose import sets up EGL for rendering
with no display.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fracture.errors import InputError


def check_size(width: int, height: int, where: str = "render") -> None:
    """Image sizes an MP4 (yuv420p) can hold: even, at least 64 pixels, at most 8192."""
    for name, v in (("width", width), ("height", height)):
        if not isinstance(v, (int, np.integer)) or not 64 <= v <= 8192 or v % 2:
            raise InputError(f"{where}: {name} must be an even number of pixels in 64..8192, got {v!r}")


class Video:
    """An MP4 (H.264, yuv420p) written frame by frame to a temporary file, renamed into place on close."""

    def __init__(self, path: Path, width: int, height: int, fps: int):
        import imageio_ffmpeg

        if not 1 <= fps <= 240:
            raise InputError(f"fps must be in 1..240, got {fps}")
        self.path = Path(path)
        self.tmp = self.path.with_name(f".{self.path.stem}.partial.mp4")
        self.size = (width, height)
        self.writer = imageio_ffmpeg.write_frames(str(self.tmp), self.size, fps=fps, codec="libx264",
                                                  pix_fmt_in="rgb24", pix_fmt_out="yuv420p", quality=8,
                                                  macro_block_size=2, ffmpeg_log_level="error")
        self.writer.send(None)

    def add(self, image: np.ndarray) -> None:
        if image.shape[:2] != (self.size[1], self.size[0]):
            raise ValueError(f"frame of size {image.shape[1]}x{image.shape[0]}, video is {self.size[0]}x{self.size[1]}")
        self.writer.send(np.ascontiguousarray(image, np.uint8))

    def close(self) -> None:
        self.writer.close()
        os.replace(self.tmp, self.path)

    def abort(self) -> None:
        try:
            self.writer.close()
        finally:
            self.tmp.unlink(missing_ok=True)


def frame_counts(n: int, seconds: float, fps: int) -> list[int]:
    """Video frames for each of ``n`` images shown ``seconds`` each at ``fps``: image i ends at frame
    round((i + 1) * seconds * fps), so the pace is kept on average (an animation plays at its own
    rate whatever the video's; images are dropped when they come faster than the video's frames).
    The first image is always shown."""
    r = seconds * fps
    ends = [max(1, round((i + 1) * r)) for i in range(n)]
    return [b - a for a, b in zip([0] + ends[:-1], ends)]


@dataclass(frozen=True)
class Timing:
    """How long a video shows each image: ``fps`` video frames a second, each image ``image_seconds``
    (None: the view's own pace), the last image held ``hold`` seconds more."""

    fps: int = 24
    image_seconds: float | None = None
    hold: float = 1.0

    def check(self) -> "Timing":
        """Itself, if its values are in range; else an InputError naming the render's flag that set the value."""
        if not 1 <= self.fps <= 240:
            raise InputError(f"--fps must be in 1..240 video frames a second, got {self.fps}")
        if self.image_seconds is not None and not 0 < self.image_seconds <= 60:
            raise InputError(f"--image-seconds must be in (0, 60], got {self.image_seconds}")
        if not 0 <= self.hold <= 60:
            raise InputError(f"--hold must be in 0..60 seconds, got {self.hold}")
        return self

    def counts(self, n: int, default_seconds: float) -> list[int]:
        """Video frames of each of ``n`` images, the last one's hold included."""
        s = self.image_seconds if self.image_seconds is not None else default_seconds
        counts = frame_counts(n, s, self.fps)
        if counts:
            counts[-1] += round(self.hold * self.fps)
        return counts

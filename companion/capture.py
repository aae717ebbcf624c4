"""Frame sources: timestamped frames from a video file.

Every user mistake (missing file, directory, empty file, a file that is not a video)
raises :class:`CaptureError` with a one-line message, never an OpenCV traceback.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# OpenCV and FFmpeg print their own warnings on bad files; our one line is enough.
os.environ.setdefault("OPENCV_LOG_LEVEL", "OFF")
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")

import cv2  # noqa: E402

__all__ = ["CaptureError", "Frame", "VideoFile"]


class CaptureError(RuntimeError):
    """A frame source that cannot be opened or read; the message is one line."""


@dataclass(frozen=True)
class Frame:
    """One frame: ``index`` from 0, ``t_s`` its time in the source (seconds), BGR pixels."""

    index: int
    t_s: float
    image: np.ndarray


class VideoFile:
    """Frames of a video file, in order. ``len()`` is the container's frame count
    (0 when unknown). Use as a context manager or call :meth:`close`."""

    def __init__(self, path: str | Path):
        p = Path(path)
        if not p.exists():
            raise CaptureError(f"video not found: {p}")
        if p.is_dir():
            raise CaptureError(f"{p} is a directory, not a video file")
        if p.stat().st_size == 0:
            raise CaptureError(f"{p} is empty (0 bytes)")
        if not os.access(p, os.R_OK):
            raise CaptureError(f"{p} is not readable (permission denied)")
        self.path = p
        self._cap = cv2.VideoCapture(str(p))
        ok, first = self._cap.read() if self._cap.isOpened() else (False, None)
        if not ok or first is None:
            self._cap.release()
            raise CaptureError(f"{p} is not a video OpenCV can decode")
        self._first: np.ndarray | None = first
        fps = self._cap.get(cv2.CAP_PROP_FPS)
        self.fps = fps if fps and np.isfinite(fps) and fps > 0 else 30.0
        self.width, self.height = first.shape[1], first.shape[0]
        count = int(self._cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        self._count = max(count, 0)

    def __len__(self) -> int:
        return self._count

    def __iter__(self) -> Iterator[Frame]:
        index = 0
        while True:
            if self._first is not None:
                image, self._first = self._first, None
            else:
                ok, image = self._cap.read()
                if not ok or image is None:
                    return
            yield Frame(index, index / self.fps, image)
            index += 1

    def close(self) -> None:
        self._cap.release()

    def __enter__(self) -> VideoFile:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

"""Frame sources: a video file, an image folder, a V4L2 camera; and the newest-frame reader.

Every user mistake (missing file, empty file, a file that is not a video, an empty
folder, a camera that is not there) raises :class:`CaptureError` with a one-line message,
never an OpenCV traceback. :class:`LatestFrame` runs a source on its own thread and keeps
only the newest frame, so a slow consumer drops frames instead of falling behind.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

# OpenCV and FFmpeg print their own warnings on bad files; our one line is enough.
os.environ.setdefault("OPENCV_LOG_LEVEL", "OFF")
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")

import cv2  # noqa: E402

__all__ = ["Camera", "CaptureError", "Frame", "ImageFolder", "LatestFrame", "VideoFile",
           "is_camera", "open_recording", "open_source"]

log = logging.getLogger("companion.capture")
IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm"}


class CaptureError(RuntimeError):
    """A frame source that cannot be opened or read; the message is one line."""


@dataclass(frozen=True)
class Frame:
    """One frame: ``index`` from 0, ``t_s`` its time in the source (seconds), BGR pixels,
    ``captured_s`` the time.monotonic() it was read, ``source`` a file name if any."""

    index: int
    t_s: float
    image: np.ndarray
    captured_s: float = 0.0
    source: str | None = None


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


class ImageFolder:
    """The images of a folder in name order; other files are skipped with a warning."""

    def __init__(self, path: str | Path, fps: float = 10.0):
        p = Path(path)
        if not p.is_dir():
            raise CaptureError(f"{p} is not a folder")
        self.path, self.fps = p, fps
        self._files = []
        for f in sorted(p.iterdir()):
            if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES:
                self._files.append(f)
            elif f.is_file():
                log.warning("skipping %s: not an image", f.name)
        if not self._files:
            raise CaptureError(f"no images in folder {p}")
        first = cv2.imread(str(self._files[0]), cv2.IMREAD_COLOR)
        self.height, self.width = first.shape[:2] if first is not None else (0, 0)

    def __len__(self) -> int:
        return len(self._files)

    def __iter__(self) -> Iterator[Frame]:
        index = 0
        for f in self._files:
            image = cv2.imread(str(f), cv2.IMREAD_COLOR)
            if image is None:
                log.warning("skipping %s: not an image OpenCV can decode", f.name)
                continue
            yield Frame(index, index / self.fps, image, time.monotonic(), f.name)
            index += 1

    def close(self) -> None:
        pass

    def __enter__(self) -> ImageFolder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Camera:
    """A V4L2 camera by index (``0``) or path (``/dev/video0``), opened at the requested
    size, rate and FOURCC (the driver may pick the nearest it supports)."""

    def __init__(self, device: str | int, width: int = 640, height: int = 480,
                 fps: float = 30.0, fourcc: str = "MJPG"):
        self.device = device
        dev = int(device) if isinstance(device, int) or str(device).isdigit() else str(device)
        if isinstance(dev, str) and not Path(dev).exists():
            raise CaptureError(f"camera {dev} not found")
        self._cap = cv2.VideoCapture(dev, cv2.CAP_V4L2)
        if not self._cap.isOpened():
            raise CaptureError(f"camera {device} could not be opened")
        if fourcc:
            self._cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*fourcc[:4].ljust(4)))
        self._cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
        self._cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
        self._cap.set(cv2.CAP_PROP_FPS, fps)
        self.fps = self._cap.get(cv2.CAP_PROP_FPS) or fps
        self._t0 = time.monotonic()

    def __iter__(self) -> Iterator[Frame]:
        index = 0
        while True:
            ok, image = self._cap.read()
            if not ok or image is None:
                raise CaptureError(f"camera {self.device} stopped delivering frames")
            now = time.monotonic()
            yield Frame(index, now - self._t0, image, now)
            index += 1

    def close(self) -> None:
        self._cap.release()


def open_recording(path: str | Path) -> VideoFile | ImageFolder:
    """A video file, or a folder of images."""
    return ImageFolder(path) if Path(path).is_dir() else VideoFile(path)


def is_camera(spec: str | int) -> bool:
    """A camera index (``0``) or device path (``/dev/video0``), not a recording: a file or
    folder of that name (``/dev/shm/flight.mp4``) is a recording."""
    text = str(spec)
    if Path(text).is_file() or Path(text).is_dir():
        return False
    return text.isdigit() or text.startswith("/dev/")


def open_source(spec: str | int, camera_size=(640, 480), camera_fps=30.0, fourcc="MJPG"):
    """A video file, an image folder, or a camera (an index or a /dev path)."""
    text = str(spec)
    if is_camera(text):
        return Camera(text, *camera_size, camera_fps, fourcc)
    return open_recording(text)


class LatestFrame:
    """Reads a source on its own thread and keeps only the newest frame.

    ``open_source()`` (a callable returning a source) is called again with backoff
    (``retry_s`` doubling up to ``max_retry_s``) when the source fails, e.g. a camera
    unplugged; each failure is reported through ``on_event``. ``realtime`` paces a
    recording at its frame rate, as a camera would deliver it. When a finite source ends,
    :attr:`ended` is set. :meth:`get` returns the newest frame not yet taken.
    """

    def __init__(self, open_source: Callable[[], object], realtime: bool = True,
                 retry_s: float = 0.5, max_retry_s: float = 5.0,
                 on_event: Callable[[str], None] = lambda text: None):
        self._open, self._realtime = open_source, realtime
        self._retry_s, self._max_retry_s = retry_s, max_retry_s
        self.on_event = on_event
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self._taken = True
        self._stop = threading.Event()
        self.ended = threading.Event()
        self.read = 0  # frames read from the source
        self.dropped = 0  # frames replaced before anyone took them
        self._thread = threading.Thread(target=self._run, name="capture", daemon=True)

    def start(self) -> LatestFrame:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        self._thread.join(timeout=2.0)

    def get(self, timeout_s: float) -> Frame | None:
        """The newest untaken frame, waiting up to ``timeout_s``; None if none came."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._taken:
                left = deadline - time.monotonic()
                if left <= 0 or self._stop.is_set() or self.ended.is_set():
                    return None
                self._cond.wait(left)
            self._taken = True
            return self._frame

    def _publish(self, frame: Frame) -> None:
        with self._cond:
            if not self._taken:
                self.dropped += 1
            self._frame, self._taken = frame, False
            self.read += 1
            self._cond.notify_all()

    def _run(self) -> None:
        delay = self._retry_s
        index = 0
        while not self._stop.is_set():
            try:
                source = self._open()
            except CaptureError as exc:
                self.on_event(f"{exc}; retrying in {delay:.1f} s")
                self._stop.wait(delay)
                delay = min(delay * 2, self._max_retry_s)
                continue
            delay = self._retry_s
            fps = getattr(source, "fps", 0.0) or 0.0
            t_start = time.monotonic()
            try:
                for frame in source:
                    if self._stop.is_set():
                        return
                    if self._realtime and fps > 0 and not isinstance(source, Camera):
                        lag = t_start + frame.t_s - time.monotonic()
                        if lag > 0 and self._stop.wait(lag):
                            return
                    self._publish(replace(frame, index=index, captured_s=time.monotonic()))
                    index += 1
            except CaptureError as exc:
                self.on_event(f"{exc}; reopening")
                continue
            finally:
                source.close()
            if not isinstance(source, Camera):
                self.ended.set()
                with self._cond:
                    self._cond.notify_all()
                return

"""Worker processes of the simulation and evaluation commands."""

from __future__ import annotations

import multiprocessing

SPAWN = multiprocessing.get_context("spawn")
"""Workers start fresh (spawned), not forked: a fork of a process whose OpenCV thread pool
has run (a test session, a caller that ran the pipeline) can hang in its first cv2 call."""

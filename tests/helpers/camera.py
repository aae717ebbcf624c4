"""A camera's attitude for the synthetic geometry tests."""

import math

import numpy as np


def tilted_camera(pitch_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    """Rotation (3×3) from a levelled camera frame (x right, y down, z forward) into the
    same camera pitched ``pitch_deg`` nose down (negative: nose up), then rolled
    ``roll_deg`` about its optical axis. ``rot @ p`` is a levelled point in the tilted
    camera's frame; ``rot @ (0, 1, 0)`` is the true down direction there."""
    p, r = math.radians(pitch_deg), math.radians(roll_deg)
    pitch = np.array([[1.0, 0.0, 0.0],
                      [0.0, math.cos(p), -math.sin(p)],
                      [0.0, math.sin(p), math.cos(p)]])
    roll = np.array([[math.cos(r), -math.sin(r), 0.0],
                     [math.sin(r), math.cos(r), 0.0],
                     [0.0, 0.0, 1.0]])
    return roll @ pitch

"""Outputs for people: the JSON-lines decision log and annotated frames.

The log record is a contract (see DESIGN.md): exactly the keys of :data:`LOG_KEYS`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import IO

import cv2
import numpy as np

from companion.control.policy import TurnCommand
from companion.vision.geometry import to_pixels
from companion.vision.pipeline import Estimate
from companion.vision.vanishing import NONE, V1, V2, V3

__all__ = ["LOG_KEYS", "log_record", "DecisionLog", "annotate", "Summary", "closing_line"]

LOG_KEYS = (
    "frame",
    "t",
    "eta_deg",
    "phi_deg",
    "obstacles",
    "action",
    "yaw_rate_deg_s",
    "latency_ms",
    "source",
    "layout_vps",
    "focal_px",
    "eta_tracked_deg",
    "range_m",
)

# BGR colours: V1 red, V2 green, V3 blue, obstacle legs yellow, unassigned grey.
_LABEL_COLOURS = {V1: (40, 40, 230), V2: (40, 200, 40), V3: (230, 120, 30), NONE: (150, 150, 150)}
_OBSTACLE = (0, 220, 255)
_NOISE = (90, 90, 90)  # dropped as noise: darker than the unassigned grey


def closing_line(seconds: float, command: str, config: str | None = None) -> str:
    """The last line an evaluation prints: how long it took and the command that measures
    the same again, with the config it ran on, so that a figure copied with it carries
    its whole command: ``(12 s; companion eval … --config c.yaml)``."""
    return f"({seconds:.0f} s; {command}{f' --config {config}' if config else ''})"


def _round(x: float | None, nd: int = 3) -> float | None:
    return None if x is None else round(float(x), nd)


def layout_vps_record(est: Estimate) -> list[list[float] | None]:
    """V1, V2, V3 as ``[x, y, w]`` pixels (``w = 1``; ``w = 0`` at infinity), null if absent.

    A row is given when segments support it, or when the layout was found and the row
    was inferred from the other two (V2 ⟂ V1, V3).
    """
    rows: list[list[float] | None] = []
    for i in range(3):
        if i not in est.layout.usable_rows:
            rows.append(None)
            continue
        x, y, w = (float(v) for v in est.layout.vps[i])
        if abs(w) > 1e-9 and max(abs(x / w), abs(y / w)) < 1e9:
            rows.append([round(x / w, 3), round(y / w, 3), 1.0])
        else:
            n = max(np.hypot(x, y), 1e-300)
            rows.append([round(x / n, 6), round(y / n, 6), 0.0])
    return rows


def log_record(frame: int, t: float, est: Estimate, cmd: TurnCommand, latency_ms: float,
               source: str | None = None) -> dict:
    """One JSON-lines record, keys exactly :data:`LOG_KEYS`."""
    return {
        "frame": int(frame),
        "t": round(float(t), 4),
        "eta_deg": _round(est.eta_deg),
        "phi_deg": _round(est.phi_deg),
        "obstacles": len(est.obstacles),
        "action": cmd.action,
        "yaw_rate_deg_s": round(float(cmd.yaw_rate_deg_s), 3),
        "latency_ms": round(float(latency_ms), 3),
        "source": source,
        "layout_vps": layout_vps_record(est),
        "focal_px": round(float(est.focal_px), 3),
        "eta_tracked_deg": _round(est.eta_tracked_deg),
        "range_m": _round(est.range_m),
    }


class DecisionLog:
    """Writes records as JSON lines, flushed per record so nothing is lost on a crash."""

    def __init__(self, stream: IO[str]):
        self._stream = stream

    def write(self, record: dict) -> None:
        self._stream.write(json.dumps(record, separators=(",", ":")) + "\n")
        self._stream.flush()


@dataclass
class Summary:
    """Running figures for the end-of-run summary."""

    frames: int = 0
    with_obstacle: int = 0
    eta_min: float | None = None
    eta_max: float | None = None

    def __post_init__(self):
        self.latencies: list[float] = []
        self.learning: list[bool] = []

    def add(self, est: Estimate, latency_ms: float, learning_lens: bool = False) -> None:
        """One frame; ``learning_lens``: the frame also searched the lens
        (:attr:`~companion.vision.pipeline.Pipeline.learning_lens` before it ran)."""
        self.frames += 1
        self.latencies.append(latency_ms)
        self.learning.append(learning_lens)
        if est.eta_deg is not None:
            self.with_obstacle += 1
            self.eta_min = est.eta_deg if self.eta_min is None else min(self.eta_min, est.eta_deg)
            self.eta_max = est.eta_deg if self.eta_max is None else max(self.eta_max, est.eta_deg)

    def lines(self, wall_s: float) -> list[str]:
        lat = np.array(self.latencies) if self.latencies else np.zeros(1)
        eta = f"{self.eta_min:+.1f}° … {self.eta_max:+.1f}°" if self.eta_min is not None else "none"
        fps = self.frames / wall_s if wall_s > 0 else 0.0
        after = lat[~np.array(self.learning, bool)] if self.latencies else lat
        # The first frames of a video also search the lens: they, not the steady state,
        # make the p95 of a short recording.
        steady = (f" ({np.percentile(after, 95):.1f} ms after the {len(lat) - len(after)} "
                  "frames that learnt the lens)") if 0 < len(after) < len(lat) else ""
        out = [
            f"frames: {self.frames}   with obstacle: {self.with_obstacle}   η range: {eta}",
            f"latency: median {np.median(lat):.1f} ms, p95 {np.percentile(lat, 95):.1f} ms"
            f"{steady}   throughput: {fps:.1f} fps",
        ]
        return out


def _clip_point(p: np.ndarray, w: int, h: int) -> tuple[int, int]:
    return int(np.clip(p[0], -10 * w, 11 * w)), int(np.clip(p[1], -10 * h, 11 * h))


def _draw_vp(img: np.ndarray, vp: np.ndarray, colour, label: str) -> None:
    """A VP inside the frame is a circle; outside (or at infinity) an arrow at the border."""
    h, w = img.shape[:2]
    c = np.array([w / 2.0, h / 2.0])
    p = to_pixels(vp)
    if p is not None and 0 <= p[0] < w and 0 <= p[1] < h:
        cv2.circle(img, (int(p[0]), int(p[1])), 6, colour, 2, cv2.LINE_AA)
        _label(img, label, (int(p[0]) + 8, int(p[1]) - 8), colour)
        return
    d = (vp[:2] - vp[2] * c) * (1 if vp[2] >= 0 else -1)
    if np.linalg.norm(d) < 1e-12:
        return
    d = d / np.linalg.norm(d)
    s = min((w / 2 - 14) / max(abs(d[0]), 1e-9), (h / 2 - 14) / max(abs(d[1]), 1e-9))
    tip = c + d * s
    tail = tip - d * 28
    cv2.arrowedLine(
        img,
        (int(tail[0]), int(tail[1])),
        (int(tip[0]), int(tip[1])),
        colour,
        2,
        cv2.LINE_AA,
        tipLength=0.4,
    )
    _label(img, label, (int(tail[0]) - 8, int(tail[1]) - 6), colour)


_FONT = cv2.FONT_HERSHEY_SIMPLEX
_BAND = (32, 32, 32)


def _label(img: np.ndarray, text: str, org: tuple[int, int], colour, scale: float = 0.45
           ) -> int:
    """``text`` in ``colour`` on a solid dark box (legible on any background), its
    baseline at ``org``; returns the x just past it."""
    (tw, th), base = cv2.getTextSize(text, _FONT, scale, 1)
    x, y = org
    cv2.rectangle(img, (x - 2, y - th - 3), (x + tw + 2, y + base), _BAND, cv2.FILLED)
    cv2.putText(img, text, (x, y), _FONT, scale, colour, 1, cv2.LINE_AA)
    return x + tw + 4


LEGEND = (("V1", _LABEL_COLOURS[V1]), ("V2", _LABEL_COLOURS[V2]),
          ("V3 vertical", _LABEL_COLOURS[V3]), ("obstacle: legs, corners, O1 O2", _OBSTACLE),
          ("unassigned", _LABEL_COLOURS[NONE]), ("η arrow", (0, 0, 255)), ("noise", _NOISE))
"""What each colour of :func:`annotate` is: segments pointing at V1, V2, V3; the obstacle's
legs, corner points and OVPs; segments of no VP; the arrow turned by η; unassigned segments
dropped as noise (``vision.min_step_z``)."""


def annotate(frame: np.ndarray, est: Estimate, cmd: TurnCommand | None = None) -> np.ndarray:
    """A copy of ``frame`` with segments coloured by VP, the layout VPs, obstacle corners
    and OVPs, and an arrow showing η (length grows with |η|)."""
    img = frame.copy() if frame.ndim == 3 else cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    h, w = img.shape[:2]
    legs: set[int] = set()
    for k in range(len(est.obstacle_corners)):
        legs.update((int(est.obstacle_corners.s[k]), int(est.obstacle_corners.n[k])))
    for seg in est.noise_segments:
        cv2.line(img, _clip_point(seg[:2], w, h), _clip_point(seg[2:], w, h), _NOISE, 1,
                 cv2.LINE_AA)
    for i, seg in enumerate(est.segments):
        colour = (
            _OBSTACLE if i in legs else _LABEL_COLOURS.get(int(est.labels[i]), _LABEL_COLOURS[NONE])
        )
        cv2.line(
            img, _clip_point(seg[:2], w, h), _clip_point(seg[2:], w, h), colour, 1, cv2.LINE_AA
        )
    if est.layout.observed[V1] or est.layout.observed[V3]:
        for k, name in ((V1, "V1"), (V2, "V2"), (V3, "V3")):
            _draw_vp(img, est.layout.vps[k], _LABEL_COLOURS[k], name)
    for ob in est.obstacles:
        for p in ob.corners_px:
            cv2.circle(img, (int(p[0]), int(p[1])), 5, _OBSTACLE, 2, cv2.LINE_AA)
        for k in (0, 1):
            _draw_vp(img, ob.ovps[k], _OBSTACLE, f"O{k + 1}")
    # η arrow from the centre: straight up for 0, turned by η.
    c = (w // 2, h - 40)
    if est.eta_deg is not None:
        a = math.radians(est.eta_deg)
        tip = (int(c[0] + 60 * math.sin(a)), int(c[1] - 60 * math.cos(a)))
        cv2.arrowedLine(img, c, tip, (0, 0, 255), 3, cv2.LINE_AA, tipLength=0.25)
    # Hershey fonts have no η or °: spelled out.
    text = "eta: none" if est.eta_deg is None else f"eta {est.eta_deg:+.1f} deg"
    if est.eta_tracked_deg is not None:
        text += f"  tracked {est.eta_tracked_deg:+.1f} deg"
    if cmd is not None:
        text += f"  {cmd.action}  {cmd.yaw_rate_deg_s:+.1f} deg/s"
    scale = 0.5 if w >= 480 else 0.38
    band = int(26 * scale / 0.5)
    cv2.rectangle(img, (0, 0), (w, band), _BAND, cv2.FILLED)
    cv2.putText(img, text, (8, int(band * 0.72)), _FONT, scale, (255, 255, 255), 1, cv2.LINE_AA)
    # The legend along the bottom, each name in its colour.
    small = scale * 0.8
    cv2.rectangle(img, (0, h - band + 4), (w, h), _BAND, cv2.FILLED)
    x = 6
    for name, colour in LEGEND:
        name = name.replace("η", "eta")
        if x + cv2.getTextSize(name, _FONT, small, 1)[0][0] > w:
            break
        cv2.putText(img, name, (x, h - 6), _FONT, small, colour, 1, cv2.LINE_AA)
        x += cv2.getTextSize(name, _FONT, small, 1)[0][0] + 12
    return img

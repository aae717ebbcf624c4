"""Per-frame evaluation results, written as JSON lines and compared between two runs.

A rule change is decided on a dev split by what it does frame by frame: which detections
it gains and loses, which false alarms it adds or removes, whose η error it moves. The
pooled rows of ``companion eval`` hide that (a gained and a lost detection cancel), so
``companion eval --renderer R --split dev --frames OLD.jsonl`` on one commit and
``--frames NEW.jsonl`` on another, then ``companion eval --diff OLD.jsonl NEW.jsonl``,
list the frames that changed.

Each line is one frame: where it came from (``renderer``, ``split``, ``seed``,
``camera``, ``view``), how the run read it (``reading``) and every field of
:class:`~sitl.evaluate.SceneResult`. A frame is identified by ``renderer``, ``split``,
``seed``, ``camera``, ``view``, ``index`` and ``mirrored``: the same frame read two ways
(each frame alone, or the split run as a video) is compared, and the diff says so; a room
seen from elsewhere (``--eye-level``, ``--pitch``) is another frame.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from pathlib import Path

__all__ = ["FrameChange", "view_of", "reading_of", "frame_rows", "read_frames", "frame_changes",
           "format_changes"]

KEY_FIELDS = ("renderer", "split", "seed", "camera", "view", "index", "mirrored")
"""the fields that identify a frame across runs"""

AS_DRAWN = "as drawn"
"""the ``view`` of a room seen from where its draw put the camera (files written before
rows had a ``view`` hold only such frames)"""

EACH_FRAME = "each frame alone"
"""the ``reading`` of a run that scores every frame through a pipeline of its own (files
written before rows had a ``reading`` hold only such runs)"""

OUTCOME_FIELDS = ("has_obstacle", "detectable", "eta_true_deg", "eta_est_deg")
"""the fields :func:`frame_changes` compares"""


def view_of(eye_level: bool = False, pitch_deg: float = 0.0, rug: bool = False) -> str:
    """A row's ``view``: where the camera stood (``--eye-level``, ``--pitch``) and what was
    laid in front of it (``--rug``)."""
    where = (["eye level"] if eye_level else []) + (
        [f"pitched {pitch_deg:g}°"] if pitch_deg else []) + (["a rug laid"] if rug else [])
    return ", ".join(where) or AS_DRAWN


def reading_of(as_video: bool = False, focal_given: bool = False,
               lens_given: bool = False) -> str:
    """A row's ``reading``: how the run read its frames (``--as-video``, the focal length
    or the lens given)."""
    return ", ".join(["as a video" if as_video else EACH_FRAME]
                     + (["focal length given"] if focal_given else [])
                     + (["lens given"] if lens_given else []))


def frame_rows(results: Iterable, renderer: str, split: str | None, seed: int,
               camera: str, view: str = AS_DRAWN, reading: str = EACH_FRAME) -> list[dict]:
    """One dict per :class:`~sitl.evaluate.SceneResult` of a run, with where it came from:
    ``renderer``, ``split`` (None outside the frozen splits), ``seed``, ``camera`` (a
    label of :data:`~sitl.evaluate.CAMERAS` or ``W×H``), ``view`` (where the camera
    stands, e.g. ``eye level, pitched 10°``), and how the run read it: ``reading`` (e.g.
    ``as a video, focal length given``)."""
    return [{"renderer": renderer, "split": split, "seed": seed, "camera": camera,
             "view": view, "reading": reading, **asdict(r)} for r in results]


def read_frames(path: str | Path) -> list[dict]:
    """The rows of a ``--frames`` file, those of a file written before rows had a ``view``
    and a ``reading`` given the only ones there were. Raises ValueError, naming the line,
    on one that is not a frame row."""
    rows = []
    with open(path, encoding="utf-8") as f:
        for n, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                raise ValueError(f"{path}:{n}: not JSON") from None
            if isinstance(row, dict):
                row.setdefault("view", AS_DRAWN)
                row.setdefault("reading", EACH_FRAME)
            if not isinstance(row, dict) or any(k not in row
                                                for k in KEY_FIELDS + OUTCOME_FIELDS):
                raise ValueError(f"{path}:{n}: not a frame row (companion eval --frames)")
            rows.append(row)
    return rows


@dataclass(frozen=True)
class FrameChange:
    """How one frame's outcome differs between two runs.

    ``what``: ``gained`` (a detectable obstacle now given an η), ``lost`` (no longer),
    ``false alarm`` (an η on a frame with no rotated obstacle, not there before),
    ``false alarm gone``, or ``eta`` (detected in both, the η error moved by more than the
    tolerance). ``old_err_deg``, ``new_err_deg``: |η estimated − η true| in each run,
    None where there is no η (or no truth).
    """

    renderer: str
    split: str | None
    seed: int
    camera: str
    index: int
    mirrored: bool
    what: str
    kind: str | None
    eta_true_deg: float | None
    old_eta_deg: float | None
    new_eta_deg: float | None
    view: str = AS_DRAWN
    old_rule: str | None = None  # the rule that read the obstacle driving η, in each run
    new_rule: str | None = None

    @property
    def old_err_deg(self) -> float | None:
        return _err(self.old_eta_deg, self.eta_true_deg)

    @property
    def new_err_deg(self) -> float | None:
        return _err(self.new_eta_deg, self.eta_true_deg)


def _err(eta: float | None, truth: float | None) -> float | None:
    return None if eta is None or truth is None else abs(eta - truth)


def _key(row: dict) -> tuple:
    return tuple(row[k] for k in KEY_FIELDS)


def frame_changes(old: list[dict], new: list[dict], eta_tol_deg: float = 1.0
                  ) -> tuple[list[FrameChange], int]:
    """The frames whose outcome differs between ``old`` and ``new`` rows, in ``new``'s
    order, and how many frames the two runs share. Frames in only one run are not
    compared. A detectable frame changes when it gains or loses its η, or when its η error
    moves by more than ``eta_tol_deg`` degrees; a frame without a rotated obstacle, when
    it gains or loses an η (a false alarm)."""
    before = {_key(r): r for r in old}
    changes = []
    shared = 0
    for r in new:
        o = before.get(_key(r))
        if o is None:
            continue
        shared += 1
        was, now = o["eta_est_deg"], r["eta_est_deg"]
        what = None
        if r["detectable"]:
            if (was is None) != (now is None):
                what = "gained" if now is not None else "lost"
            elif now is not None:
                moved = abs(_err(now, r["eta_true_deg"]) - _err(was, o["eta_true_deg"]))
                what = "eta" if moved > eta_tol_deg else None
        elif not r["has_obstacle"] and (was is None) != (now is None):
            what = "false alarm" if now is not None else "false alarm gone"
        if what:
            changes.append(FrameChange(r["renderer"], r["split"], r["seed"], r["camera"],
                                       r["index"], r["mirrored"], what, r.get("kind"),
                                       r["eta_true_deg"], was, now, r["view"],
                                       o.get("rule"), r.get("rule")))
    return changes, shared


WHAT_ORDER = ("gained", "lost", "false alarm", "false alarm gone", "eta")


def format_changes(changes: list[FrameChange], shared: int, eta_tol_deg: float = 1.0,
                   old_reading: str | None = None, new_reading: str | None = None
                   ) -> list[str]:
    """Printable lines: a count per kind of change for each renderer, split and camera,
    then one line per changed frame. Where the two runs read their frames differently
    (``old_reading``, ``new_reading``), the first line says how each did."""

    def deg(x: float | None) -> str:
        return "—" if x is None else f"{x:+.1f}°"

    lines = [f"{shared} frames in both runs; {len(changes)} changed "
             f"(an η error that moved by more than {eta_tol_deg:g}° counts)"]
    if old_reading != new_reading:
        lines[0] += f"; old run: {old_reading}; new run: {new_reading}"
    groups: dict[tuple, list[FrameChange]] = {}
    for c in changes:
        groups.setdefault((c.renderer, c.split, c.seed, c.camera, c.view), []).append(c)
    for (renderer, split, seed, camera, view), cs in groups.items():
        counts = ", ".join(f"{sum(c.what == w for c in cs)} {w}" for w in WHAT_ORDER
                           if any(c.what == w for c in cs))
        where = f"{renderer} {split}" if split else f"{renderer} seed {seed}"
        where += "" if view == AS_DRAWN else f", {view}"
        lines.append(f"{camera}, {where}: {counts}")
        for c in sorted(cs, key=lambda c: (WHAT_ORDER.index(c.what), c.index, c.mirrored)):
            frame = f"{c.index}{' mirrored' if c.mirrored else ''}"
            err = ""
            if c.what == "eta":
                err = f"  error {c.old_err_deg:.1f}° → {c.new_err_deg:.1f}°"
            if c.old_rule or c.new_rule:
                err += f"  by {c.old_rule or '—'} → {c.new_rule or '—'}"
            lines.append(f"  {frame:<14} {c.what:<17} {c.kind or '':<8} true {deg(c.eta_true_deg)}"
                         f"  η {deg(c.old_eta_deg)} → {deg(c.new_eta_deg)}{err}")
    return lines

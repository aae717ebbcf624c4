"""Layout-VP accuracy on the York Urban Database (real photographs, hand-labelled VPs).

Behind ``companion eval --yud DIR``. The data stays where it is (``../shared/data/yud``);
nothing of it is copied into the repository. Metric, as the database's README defines it:
for each ground-truth VP, the angle between its 3-D direction and the nearest estimated
VP's direction (``K⁻¹ v``, normalised); AA@θ is the area under the cumulative error curve
from 0 to θ, divided by θ, in percent. The segment→VP assignment is scored on the
ground-truth segments: precision over the segments it assigns, recall over all of them.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from companion.config import Config
from companion.vision.geometry import principal_point
from companion.vision.pipeline import Pipeline
from companion.vision.vanishing import NONE, assign_segments
from sitl.scene import orientations

__all__ = ["VARIANTS", "YudReport", "angular_errors_deg", "area_under_curve", "evaluate_yud",
           "evaluate_yud_lu", "evaluate_yud_variants", "format_yud", "format_variants",
           "speed_side_by_side", "zoom_roll"]

THRESHOLDS_DEG = (3.0, 5.0, 10.0)


def area_under_curve(errors_deg: np.ndarray, threshold_deg: float) -> float:
    """AA@θ in percent: the mean over [0, θ] of the share of errors at most that large."""
    e = np.sort(np.asarray(errors_deg, dtype=float))
    if len(e) == 0:
        return 0.0
    # ∫0^θ F(t) dt / θ with F the empirical CDF: each error e_i < θ adds (θ - e_i) / n.
    return float(100.0 * np.clip(threshold_deg - e, 0.0, None).sum() / (len(e) * threshold_deg))


def angular_errors_deg(truth_dirs: np.ndarray, est_dirs: np.ndarray) -> np.ndarray:
    """For each true 3-D direction, the angle (deg) to the nearest estimated one (sign-free).

    90° for every truth when nothing was estimated.
    """
    t = np.asarray(truth_dirs, dtype=float)
    t = t / np.linalg.norm(t, axis=1, keepdims=True)
    if len(est_dirs) == 0:
        return np.full(len(t), 90.0)
    e = np.asarray(est_dirs, dtype=float)
    e = e / np.linalg.norm(e, axis=1, keepdims=True)
    cos = np.clip(np.abs(t @ e.T), 0.0, 1.0)
    return np.degrees(np.arccos(cos.max(axis=1)))


@dataclass(frozen=True)
class YudReport:
    split: str
    images: int
    focal_given: bool
    errors_deg: np.ndarray
    ms_per_image: float  # median, image → layout VPs (lines and VPs; what a VP detector does)
    focal_estimates_px: np.ndarray  # per image where the focal length was estimated
    true_focal_px: float
    assign_precision: float | None  # None for a method whose assignment is not scored
    assign_recall: float | None
    method: str = "companion"
    pipeline_ms_per_image: float | None = None  # median, the whole pipeline (corners, η too)

    def figures(self) -> dict[str, float | int | bool | str | None]:
        out: dict[str, float | int | bool | str | None] = {
            "method": self.method, "split": self.split, "images": self.images,
            "focal_given": self.focal_given}
        for th in THRESHOLDS_DEG:
            out[f"aa{th:g}"] = round(area_under_curve(self.errors_deg, th), 2)
        out["median_err_deg"] = round(float(np.median(self.errors_deg)), 3)
        out["ms_per_image"] = round(self.ms_per_image, 1)
        out["pipeline_ms_per_image"] = (None if self.pipeline_ms_per_image is None
                                        else round(self.pipeline_ms_per_image, 1))
        f = self.focal_estimates_px
        out["focal_estimated_on"] = int(len(f))
        out["focal_median_px"] = round(float(np.median(f)), 1) if len(f) else None
        out["assign_precision"] = (None if self.assign_precision is None
                                   else round(self.assign_precision, 3))
        out["assign_recall"] = (None if self.assign_recall is None
                                else round(self.assign_recall, 3))
        return out


@dataclass(frozen=True)
class _Yud:
    root: Path
    f_true: float
    k_inv: np.ndarray  # inverse of the true intrinsics, for the metric
    images: list[dict]

    def read(self, im: dict) -> np.ndarray:
        image = cv2.imread(str(self.root / im["file"]), cv2.IMREAD_COLOR)
        if image is None:
            raise FileNotFoundError(f"cannot read {self.root / im['file']}")
        return image

    def directions(self, vps, k_inv: np.ndarray | None = None) -> list[np.ndarray]:
        """3-D directions of homogeneous pixel VPs through the true intrinsics, or through
        ``k_inv`` (a mirrored :meth:`view`'s)."""
        k_inv = self.k_inv if k_inv is None else k_inv
        return [k_inv @ v for v in vps]

    def view(self, im: dict, mirrored: bool):
        """One photograph as the metric needs it: (image, true VP directions K×3, true
        segments N×4, inverse intrinsics). ``mirrored``: the photograph mirrored left to
        right, its truth with it (x → W − 1 − x; directions' x and the principal point's
        mirrored)."""
        image = self.read(im)
        truth = np.asarray(im["vps_dir"], dtype=float)
        segments = np.asarray(im["segments"], dtype=float).reshape(-1, 4)
        if not mirrored:
            return image, truth, segments, self.k_inv
        w = image.shape[1]
        k = np.linalg.inv(self.k_inv)
        k[0, 2] = w - 1 - k[0, 2]
        segments = segments.copy()
        segments[:, [0, 2]] = w - 1 - segments[:, [0, 2]]
        return (np.ascontiguousarray(image[:, ::-1]), truth * np.array([-1.0, 1.0, 1.0]),
                segments, np.linalg.inv(k))


TIMING_RUNS = 3


def _timed(run, *args):
    """``run(*args)`` and its wall time in ms."""
    t0 = time.perf_counter()
    out = run(*args)
    return out, (time.perf_counter() - t0) * 1e3


def _best_of(run, *args):
    """``run(*args)``'s result and its shortest wall time in ms over ``TIMING_RUNS`` calls:
    the same rule for every method, so that a busy machine slows neither more."""
    runs = [_timed(run, *args) for _ in range(TIMING_RUNS)]
    return runs[-1][0], min(ms for _, ms in runs)


def _load(folder: str | Path, split: str, limit: int | None) -> _Yud:
    root = Path(folder)
    data = json.loads((root / "yud.json").read_text())
    f_true = float(data["focal_px"])
    pp = np.asarray(data["principal_point"], dtype=float)
    k_inv = np.linalg.inv(np.array([[f_true, 0, pp[0]], [0, f_true, pp[1]], [0, 0, 1.0]]))
    images = [im for im in data["images"] if split == "all" or im["split"] == split][:limit]
    return _Yud(root, f_true, k_inv, images)


def evaluate_yud(folder: str | Path, split: str = "test", focal_given: bool = True,
                 config: Config | None = None, limit: int | None = None,
                 mirrored: bool = False) -> YudReport:
    """Run the layout-VP stage on every image of ``split`` ("train", "test" or "all"),
    or on its first ``limit`` images. ``mirrored``: then on each photograph mirrored left
    to right too (a second pipeline, as a second camera), the two pooled: twice the
    sample for a decision on the train split."""
    yud = _load(folder, split, limit)
    cfg = config or Config()
    cfg = replace(cfg, camera=replace(cfg.camera, focal_px=yud.f_true if focal_given else None))
    pipelines = {False: Pipeline(cfg), True: Pipeline(cfg)}
    errors, ms, pipeline_ms, focals = [], [], [], []
    right = assigned = total = 0
    views = [(im, flip) for flip in orientations(mirrored)
             for im in yud.images]
    for im, flip in views:
        image, truth, segs, k_inv = yud.view(im, flip)
        pipeline = pipelines[flip]
        # Timed like the peer: image in, layout VPs out (lines and VPs, no corners).
        (layout, focal_source), t = _best_of(pipeline.layout, image)
        ms.append(t)
        pipeline_ms.append(_best_of(pipeline, image)[1])
        rows = layout.usable_rows
        dirs = yud.directions(layout.vps[list(rows)], k_inv)
        errors.extend(angular_errors_deg(truth, dirs))
        if focal_source == "estimated":
            focals.append(layout.focal_px)
        # Segment assignment: estimated VP i ↔ the true VP nearest to it.
        truth = truth / np.linalg.norm(truth, axis=1, keepdims=True)
        truth_of_est = {i: int(np.argmax(np.abs(truth @ (d / np.linalg.norm(d)))))
                        for i, d in zip(rows, dirs, strict=True)}
        labels, _ = assign_segments(segs, layout.vps, cfg.vision.vanishing)
        gt = np.asarray(im["segment_vp"], dtype=int)
        for lab, g in zip(labels, gt, strict=True):
            total += 1
            if lab != NONE and lab in truth_of_est:
                assigned += 1
                right += truth_of_est[lab] == g
    return YudReport(
        split=split, images=len(views), focal_given=focal_given,
        errors_deg=np.asarray(errors), ms_per_image=float(np.median(ms)) if ms else 0.0,
        focal_estimates_px=np.asarray(focals), true_focal_px=yud.f_true,
        assign_precision=right / assigned if assigned else 0.0,
        assign_recall=right / total if total else 0.0,
        pipeline_ms_per_image=float(np.median(pipeline_ms)) if pipeline_ms else None)


def evaluate_yud_lu(folder: str | Path, split: str = "test", focal_given: bool = True,
                    limit: int | None = None) -> YudReport:
    """The same measurement for the peer lu-vp-detect (see :mod:`sitl.peers`).

    It gets the same camera as our pipeline: the true focal length or, without it, its own
    default (it cannot calibrate itself); the principal point at the image centre.
    Raises :class:`sitl.peers.PeerUnavailable` when the package is not installed.
    """
    from sitl.peers import LU_DEFAULT_FOCAL_PX, lu_vp_detector

    yud = _load(folder, split, limit)
    errors, ms = [], []
    detectors = {}
    for im in yud.images:
        image = yud.read(im)
        h, w = image.shape[:2]
        if (w, h) not in detectors:
            detectors[(w, h)] = lu_vp_detector(
                yud.f_true if focal_given else LU_DEFAULT_FOCAL_PX,
                ((w - 1) / 2.0, (h - 1) / 2.0))
        vps, t = _best_of(detectors[(w, h)], image)
        ms.append(t)
        errors.extend(angular_errors_deg(np.asarray(im["vps_dir"], dtype=float),
                                         yud.directions(vps)))
    return YudReport(
        split=split, images=len(yud.images), focal_given=focal_given,
        errors_deg=np.asarray(errors), ms_per_image=float(np.median(ms)) if ms else 0.0,
        focal_estimates_px=np.zeros(0), true_focal_px=yud.f_true,
        assign_precision=None, assign_recall=None, method="lu-vp-detect")


def speed_side_by_side(folder: str | Path, split: str = "test", config: Config | None = None,
                       limit: int | None = None) -> tuple[float, float]:
    """Median ms per image of our layout VPs and of lu-vp-detect, focal length given,
    timed in turns on each image (ours, the peer, ours, …; best of ``TIMING_RUNS`` each),
    so that a machine whose speed drifts during the run slows both alike.

    Raises :class:`sitl.peers.PeerUnavailable` when the peer is not installed.
    """
    from sitl.peers import lu_vp_detector

    yud = _load(folder, split, limit)
    cfg = config or Config()
    pipeline = Pipeline(replace(cfg, camera=replace(cfg.camera, focal_px=yud.f_true)))
    ours, theirs, peers = [], [], {}
    for im in yud.images:
        image = yud.read(im)
        h, w = image.shape[:2]
        peer = peers.setdefault((w, h), lu_vp_detector(yud.f_true, ((w - 1) / 2.0,
                                                                    (h - 1) / 2.0)))
        turns = [(_timed(pipeline.layout, image)[1], _timed(peer, image)[1])
                 for _ in range(TIMING_RUNS)]
        ours.append(min(mine for mine, _ in turns))
        theirs.append(min(peer_ms for _, peer_ms in turns))
    return float(np.median(ours)), float(np.median(theirs))


def format_yud(reports: list[YudReport]) -> list[str]:
    """A table, one row per report (method × focal given or not)."""
    lines = [f"{'method':<14}{'focal':<10}{'images':>7}{'AA@3°':>8}{'AA@5°':>8}{'AA@10°':>8}"
             f"{'median':>9}{'ms/img':>8}{'assign P/R':>13}  focal estimate"]
    for r in reports:
        f = r.figures()
        est = (f"median {f['focal_median_px']} px on {f['focal_estimated_on']} images "
               f"(true {r.true_focal_px:.1f})" if f["focal_median_px"] else "—")
        pr = ("—" if f["assign_precision"] is None
              else f"{f['assign_precision']:.2f}/{f['assign_recall']:.2f}")
        focal = "given" if r.focal_given else "estimated" if r.method == "companion" else "default"
        # From the errors, not from figures(): its values are already rounded, and
        # rounding twice can move the last digit (83.4454 → 83.45 → 83.5).
        aa = "".join(f"{area_under_curve(r.errors_deg, th):>8.1f}" for th in THRESHOLDS_DEG)
        lines.append(
            f"{r.method:<14}{focal:<10}{f['images']:>7}{aa}"
            f"{float(np.median(r.errors_deg)):>8.2f}°"
            f"{f['ms_per_image']:>8.1f}{pr:>13}  {est if not r.focal_given else '—'}")
    return lines


# Harder views of the same photographs, for developing on the train split without
# touching the test split: (zoom, roll in degrees) about the principal point. A zoom
# narrows the view (fewer, shorter, blurrier lines per axis); a roll tilts every VP.
# Each zoom is large enough for its roll that the view stays inside the photograph.
VARIANTS: dict[str, tuple[float, float]] = {
    "zoom 1.5": (1.5, 0.0),
    "zoom 2": (2.0, 0.0),
    "roll +8°": (1.45, 8.0),
    "roll -8°": (1.45, -8.0),
    "roll 15°": (1.8, 15.0),
}


def zoom_roll(image: np.ndarray, focal_px: float, principal_point_px: np.ndarray, zoom: float,
              roll_deg: float) -> tuple[np.ndarray, float, np.ndarray]:
    """The view of a camera rolled by ``roll_deg`` (clockwise in the image) about its
    optical axis, with its focal length ×``zoom``, as a same-size image centred on the
    principal point.

    Returns (image, focal length in pixels, R): R (3×3) takes a direction in the
    original camera frame (x right, y down, z forward) to the new one, so the new
    image's VP of direction d is ``K' R d`` with ``K'`` the new focal length and the
    image centre ``((w - 1) / 2, (h - 1) / 2)``.
    """
    h, w = image.shape[:2]
    a = np.radians(roll_deg)
    rot2 = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    centre = principal_point(w, h)
    # x' = zoom · rot2 (x - pp) + centre, the pinhole's image of R d for every pixel.
    warp = np.c_[zoom * rot2, centre - zoom * rot2 @ np.asarray(principal_point_px, float)]
    out = cv2.warpAffine(image, warp, (w, h), flags=cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REFLECT)
    r = np.eye(3)
    r[:2, :2] = rot2
    return out, zoom * focal_px, r


def evaluate_yud_variants(folder: str | Path, split: str = "train",
                          config: Config | None = None,
                          limit: int | None = None) -> dict[str, np.ndarray]:
    """Layout-VP errors (deg, three per image), focal length given, on the photographs
    as they are (``"as is"``) and on each of :data:`VARIANTS`."""
    yud = _load(folder, split, limit)
    cfg = config or Config()
    pp = np.linalg.inv(yud.k_inv)[:2, 2]
    views = {"as is": (1.0, 0.0), **VARIANTS}
    pipelines = {name: Pipeline(replace(cfg, camera=replace(cfg.camera,
                                                            focal_px=zoom * yud.f_true)))
                 for name, (zoom, _) in views.items()}
    errors: dict[str, list[float]] = {name: [] for name in views}
    for im in yud.images:
        image = yud.read(im)
        truth = np.asarray(im["vps_dir"], dtype=float)
        for name, (zoom, roll) in views.items():
            if name == "as is":  # the true principal point, not the image centre
                view, focal, r, centre = image, yud.f_true, np.eye(3), pp
            else:
                view, focal, r = zoom_roll(image, yud.f_true, pp, zoom, roll)
                centre = principal_point(image.shape[1], image.shape[0])
            layout, _ = pipelines[name].layout(view)
            k_view = np.array([[focal, 0, centre[0]], [0, focal, centre[1]], [0, 0, 1.0]])
            dirs = [np.linalg.solve(k_view, v) for v in layout.vps[list(layout.usable_rows)]]
            errors[name].extend(angular_errors_deg((r @ truth.T).T, dirs))
    return {name: np.asarray(e) for name, e in errors.items()}


def format_variants(errors: dict[str, np.ndarray]) -> list[str]:
    """A table, one row per variant, and the mean of the rows."""
    lines = [f"{'view':<12}{'AA@3°':>8}{'AA@5°':>8}{'AA@10°':>8}{'median':>9}"]
    rows = []
    for name, e in errors.items():
        row = [area_under_curve(e, th) for th in THRESHOLDS_DEG]
        rows.append(row)
        lines.append(f"{name:<12}" + "".join(f"{x:>8.1f}" for x in row)
                     + f"{float(np.median(e)):>8.2f}°")
    mean = np.mean(rows, axis=0)
    lines.append(f"{'mean':<12}" + "".join(f"{x:>8.1f}" for x in mean))
    return lines

"""``companion eval``: the pipeline's accuracy on seeded synthetic scenes.

Two renderers draw the scenes: ``scene`` (:mod:`sitl.scene`, ray-cast, the one the stages
were developed on) and ``pathtraced`` (:mod:`sitl.pathtraced`, Mitsuba 3: soft shadows,
interreflection, textures, furniture that is not a box, lens distortion, motion blur).
Each scene ``i`` of a run with seed ``s`` is drawn from ``numpy.random.default_rng([s, i])``:
a share of them hold an obstacle rotated 12°–45° off the room's axes (with the path
tracer sometimes a second one), the rest only Manhattan structure (including furniture
aligned with the room).

Each renderer has two frozen splits (:data:`SPLITS`): ``dev``, looked at while developing,
and ``test``, only ever run whole, after a change is decided. A split is evaluated at the
three cameras of :data:`CAMERAS` without the focal length given, each frame alone (a fresh
pipeline), or with ``as_video`` each camera's frames in order through one pipeline, as
``companion --video`` runs a recording (:func:`evaluate_video`).

Figures:

- **η error**: |η − η_truth| in degrees over detected obstacles (truth: eq. 10, D = f),
  η_truth of the obstacle whose true corners lie nearest the detected ones.
- **sign wrong**: detections whose η has the opposite sign of the truth (a turn the
  wrong way), among detections with |η_truth| >= 1°.
- **detection**: share of scenes whose obstacle is detectable (see
  :mod:`sitl.scene`) in which the pipeline returned an η.
- **false positives**: share of Manhattan-only scenes in which it returned an η.
- **corner error** (the paper's Table III, LSUN convention): mean distance from each
  corner of the detected obstacle to the nearest true visible corner of the box, as a
  percentage of the image diagonal; averaged over detected scenes.

The pipeline is given the rendered camera's focal length (``camera.focal_px``, hence
D = f as the truth uses) unless ``assume_focal`` is False, in which case it estimates it
(D = the estimate) and η is compared with the same truth. With ``assume_lens`` it is also
given the lens distortion (``camera.distortion``, path-traced frames): a calibrated camera.

Path-traced frames take seconds each, so they are cached under
``$XDG_CACHE_HOME/companion/renders`` (``~/.cache`` by default), keyed by the renderer's
version, the seed, the index and the camera.
"""

from __future__ import annotations

import math
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from queue import Empty

import cv2
import numpy as np

from companion.config import Config
from companion.vision.obstacles import RULES
from companion.vision.pipeline import Pipeline
from sitl.scene import (
    RENDERERS,
    ObstacleTruth,
    SceneTruth,
    mirror,
    orientations,
    random_scene,
    render,
    rug_in_view,
)
from sitl.workers import SPAWN

__all__ = ["View", "SceneResult", "EvalReport", "evaluate_scene", "evaluate_video", "run_eval",
           "format_report", "SPLITS", "CAMERAS", "RENDERERS", "run_split", "format_splits", "CLIPS",
           "run_clips", "clip_figures", "format_clips", "drawing_order",
           "in_item_order"]

TARGETS = {
    "eta_err_median_deg": 1.5,
    "eta_err_p90_deg": 4.0,
    "detection_rate": 0.90,
    "false_positive_rate": 0.05,
    "corner_err_pct": 8.0,
}

SPLITS = {
    ("scene", "dev"): (0, 200),
    ("scene", "test"): (9001, 200),
    ("pathtraced", "dev"): (11, 240),
    ("pathtraced", "test"): (9011, 80),
}
"""(seed, scenes) of each renderer's frozen splits. Never tune on ``test``."""

CAMERAS = (
    ("640×480, 90°", 640, 480, 90.0),
    ("640×480, 60°", 640, 480, 60.0),
    ("320×240, 90°", 320, 240, 90.0),
)
"""(label, width, height, horizontal field of view) of the split rows, focal not given."""

SPLIT_TARGETS = {
    90.0: {"detection_rate": 0.95, "eta_err_median_deg": 1.0, "eta_err_p90_deg": 3.0},
    60.0: {"detection_rate": 0.90, "eta_err_median_deg": 1.5, "eta_err_p90_deg": 4.5},
    320: {"detection_rate": 0.85, "eta_err_median_deg": 1.5, "eta_err_p90_deg": 4.5},
}
"""issue 18's targets: 640×480 at 90° and at 60°, and 320×240 (keyed by width)."""


@dataclass(frozen=True)
class View:
    """How a seeded room is seen: a camera of ``width``×``height`` pixels and ``hfov_deg``
    of horizontal field of view (None: the room's own draw), the frame ``mirrored`` left to
    right (:func:`sitl.scene.mirror`), from the height of the rotated obstacle's top
    (``eye_level``, :func:`sitl.scene.at_eye_level`), pitched ``pitch_deg`` further nose
    down, with a rotated striped rug laid in front of the camera (``rug``,
    :func:`sitl.scene.rug_in_view`; the room's own rug, if any, taken up)."""

    width: int = 640
    height: int = 480
    hfov_deg: float | None = None
    mirrored: bool = False
    eye_level: bool = False
    pitch_deg: float = 0.0
    rug: bool = False


@dataclass(frozen=True)
class SceneResult:
    index: int
    has_obstacle: bool  # a non-Manhattan obstacle is in the scene
    detectable: bool
    eta_true_deg: float | None
    eta_est_deg: float | None
    corner_err_pct: float | None
    latency_ms: float
    range_est_m: float | None = None
    range_true_m: float | None = None  # the true floor corner nearest the measured one
    mirrored: bool = False  # the frame was mirrored left to right (sitl.scene.mirror)
    kind: str | None = None  # the compared obstacle's furniture kind (box, table, …)
    focal_est_px: float | None = None  # the focal length the pipeline used (given or estimated)
    focal_true_px: float | None = None
    eye_level: bool = False  # not detectable only because its top is seen edge-on
    rule: str | None = None  # the rule that read the obstacle driving η (Obstacle.rule)


def _eta_figures(seen: list[SceneResult]) -> dict[str, float | int | None]:
    """Detection and η figures over the scenes whose obstacle could be ``seen``: how many
    gave an η, its error's median and p90 (degrees), and the turns the wrong way among
    those whose true |η| is at least 1°."""
    hits = [r for r in seen if r.eta_est_deg is not None]
    err = np.array([abs(r.eta_est_deg - r.eta_true_deg) for r in hits])
    signed = [r for r in hits if abs(r.eta_true_deg) >= 1.0]
    wrong = [r for r in signed if np.sign(r.eta_est_deg) != np.sign(r.eta_true_deg)]
    return {
        "detected": len(hits),
        "detection_rate": len(hits) / len(seen) if seen else None,
        "sign_wrong": len(wrong),
        "sign_wrong_rate": len(wrong) / len(signed) if signed else None,
        "eta_err_median_deg": float(np.median(err)) if len(err) else None,
        "eta_err_p90_deg": float(np.percentile(err, 90)) if len(err) else None,
    }


RANGE_BANDS = ((1.0, 3.0), (3.0, 6.0))
"""distance bands (metres) of the range figures"""


@dataclass(frozen=True)
class EvalReport:
    scenes: int
    seed: int
    results: list[SceneResult]

    def _pick(self, pred) -> list[SceneResult]:
        return [r for r in self.results if pred(r)]

    def figures(self) -> dict[str, float | int | None]:
        det = self._pick(lambda r: r.detectable)
        hits = [r for r in det if r.eta_est_deg is not None]
        clean = self._pick(lambda r: not r.has_obstacle)
        fps = [r for r in clean if r.eta_est_deg is not None]
        hidden = self._pick(lambda r: r.has_obstacle and not r.detectable)
        corners = [r.corner_err_pct for r in hits if r.corner_err_pct is not None]
        lat = np.array([r.latency_ms for r in self.results])
        eye_seen = self._pick(lambda r: r.eye_level)
        eye = {f"eye_level_{k}": v for k, v in _eta_figures(eye_seen).items()}
        return {
            "scenes": self.scenes,
            "seed": self.seed,
            "detectable": len(det),
            **_eta_figures(det),
            "manhattan_only": len(clean),
            "false_positives": len(fps),
            "false_positive_rate": len(fps) / len(clean) if clean else None,
            "not_detectable": len(hidden),
            "not_detectable_with_eta": sum(r.eta_est_deg is not None for r in hidden),
            "corner_err_pct": float(np.mean(corners)) if corners else None,
            "latency_ms_median": float(np.median(lat)) if len(lat) else None,
            "eye_level": len(eye_seen),
            **eye,
            **self.focal_figures(),
            **self.kind_figures(),
            **self.rule_figures(),
            **self.range_figures(),
        }

    def focal_figures(self) -> dict[str, float | None]:
        """Relative error ``|f_used / f_true − 1|`` of the focal length the pipeline
        rested on, over every frame: median and p90 (0 when it was given)."""
        rel = np.array([abs(r.focal_est_px / r.focal_true_px - 1.0) for r in self.results
                        if r.focal_est_px and r.focal_true_px])
        return {"focal_err_median": float(np.median(rel)) if len(rel) else None,
                "focal_err_p90": float(np.percentile(rel, 90)) if len(rel) else None}

    def kind_figures(self) -> dict[str, int]:
        """Detectable obstacles and detections by furniture kind: ``detectable_<kind>``,
        ``detected_<kind>``."""
        out: dict[str, int] = {}
        for r in self._pick(lambda r: r.detectable and r.kind):
            out[f"detectable_{r.kind}"] = out.get(f"detectable_{r.kind}", 0) + 1
            out[f"detected_{r.kind}"] = (out.get(f"detected_{r.kind}", 0)
                                         + (r.eta_est_deg is not None))
        return out

    def rule_figures(self) -> dict[str, int]:
        """Detections and false alarms by the rule that read the obstacle driving η
        (:data:`~companion.vision.obstacles.RULES`): ``rule_detected_<rule>``,
        ``rule_false_<rule>`` (spaces as underscores), for every rule that read any."""
        out: dict[str, int] = {}
        for r in self._pick(lambda r: r.rule and (r.detectable or not r.has_obstacle)):
            rule = r.rule.replace(" ", "_")
            out[f"rule_detected_{rule}"] = out.get(f"rule_detected_{rule}", 0) + r.detectable
            out[f"rule_false_{rule}"] = out.get(f"rule_false_{rule}", 0) + (not r.detectable)
        return out

    def range_figures(self) -> dict[str, float | int | None]:
        """Relative error of ``range_m`` against the true floor contact, by distance band
        (:data:`RANGE_BANDS`): median, p90, and how many measured ranges were more than
        20 % too far (the dangerous direction)."""
        out: dict[str, float | int | None] = {}
        pairs = [(r.range_est_m, r.range_true_m) for r in self.results
                 if r.range_est_m is not None and r.range_true_m is not None]
        for lo, hi in RANGE_BANDS:
            rel = np.array([(e - t) / t for e, t in pairs if lo <= t < hi])
            key = f"range_{lo:g}_{hi:g}m"
            out[f"{key}_n"] = len(rel)
            out[f"{key}_rel_err_median"] = float(np.median(np.abs(rel))) if len(rel) else None
            out[f"{key}_rel_err_p90"] = (float(np.percentile(np.abs(rel), 90))
                                         if len(rel) else None)
            out[f"{key}_too_far"] = int(np.sum(rel > 0.2))
        return out


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "companion" / "renders"


def draw_scene(renderer: str, seed: int, index: int, obstacle_share: float = 0.7,
               view: View = View()):
    """Scene ``index`` of ``seed`` drawn by ``renderer`` as ``view`` sees it: (image BGR,
    :class:`SceneTruth`). Path-traced frames are cached on disk; a mirrored view is the
    frame and its truth mirrored, so it shares the cached frame."""
    image, truth = _draw_scene(renderer, seed, index, obstacle_share, view)
    return mirror(image, truth) if view.mirrored else (image, truth)


def _draw_scene(renderer: str, seed: int, index: int, obstacle_share: float, view: View):
    rng = np.random.default_rng([seed, index])
    has_obstacle = bool(rng.random() < obstacle_share)
    w, h = view.width, view.height
    if renderer == "scene":
        scene, cam = random_scene(rng, w, h, obstacle=has_obstacle, hfov_deg=view.hfov_deg,
                                  eye_level=view.eye_level)
        if view.rug:
            scene = replace(scene, room=_with_rug(scene.room, cam, seed, index))
        return render(scene, _pitched(cam, view.pitch_deg))
    if renderer != "pathtraced":
        raise ValueError(f"unknown renderer {renderer!r}")
    from sitl import pathtraced

    fov = "any" if view.hfov_deg is None else f"{view.hfov_deg:g}"
    eye = "eye-" if view.eye_level and has_obstacle else ""
    pitch = f"pitch{view.pitch_deg:g}-" if view.pitch_deg else ""
    rug = "rug-" if view.rug else ""
    name = f"{w}x{h}-{fov}/{rug}{pitch}{eye}{seed}-{index}-share{obstacle_share:g}.png"
    # Small frames get more samples per pixel: the same light per unit of the scene.
    spp = 16 if w * h >= 640 * 480 else 32
    r3, cam = pathtraced.random_room(rng, w, h, obstacle=has_obstacle, hfov_deg=view.hfov_deg,
                                     spp=spp, eye_level=view.eye_level)
    if view.rug:
        r3 = replace(r3, room=_with_rug(r3.room, cam, seed, index))
    return _render_cached(name, r3, _pitched(cam, view.pitch_deg))


def _with_rug(room, cam, seed: int, index: int):
    """``room`` with a rug in front of ``cam`` (:func:`sitl.scene.rug_in_view`), drawn from
    a stream of its own, so that the room and camera are the ones drawn without it."""
    return replace(room, rug=rug_in_view(np.random.default_rng([seed, index, RUG_STREAM]),
                                         room, cam))


RUG_STREAM = 7
"""the third word of the seed of ``--rug``'s rug: [split seed, room index, this]"""


def _pitched(cam, pitch_deg: float):
    """``cam`` pitched ``pitch_deg`` further nose down (the camera's own pitch is nose up
    positive): what a multicopter's fixed camera sees while it accelerates forward, or a
    camera mounted tilted down."""
    return replace(cam, pitch_deg=cam.pitch_deg - pitch_deg) if pitch_deg else cam


def _render_cached(name: str, r3, cam):
    """A path-traced frame from the cache (``name`` under this renderer version's folder),
    else rendered and cached there."""
    from sitl import pathtraced

    path = _cache_dir() / f"pathtraced-{pathtraced.VERSION}" / name
    image = cv2.imread(str(path), cv2.IMREAD_COLOR) if path.exists() else None
    if image is not None:  # the truth is cheap and always computed afresh
        return image, pathtraced.truth(r3, cam)
    image, truth = pathtraced.render(r3, cam)
    path.parent.mkdir(parents=True, exist_ok=True)
    # Two workers may render one frame at once (a scene and its mirror, with --mirrored):
    # each writes its own file, and the last replace wins with the same picture.
    tmp = path.with_suffix(f".{os.getpid()}.tmp.png")
    cv2.imwrite(str(tmp), image)
    os.replace(tmp, path)
    return image, truth


def _match(found: np.ndarray, truth: SceneTruth) -> tuple[ObstacleTruth | None, float | None]:
    """The non-Manhattan truth obstacle whose visible corners lie nearest the ``found``
    corners (N×2), and that mean distance in pixels."""
    best, best_d = None, None
    for o in truth.obstacles:
        if not o.non_manhattan or not o.corners_px:
            continue
        true_c = np.array(o.corners_px)
        d = float(np.linalg.norm(found[:, None, :] - true_c[None], axis=2).min(axis=1).mean())
        if best_d is None or d < best_d:
            best, best_d = o, d
    return best, best_d


def evaluate_scene(
    seed: int,
    index: int,
    config: Config | None = None,
    obstacle_share: float = 0.7,
    view: View = View(),
    assume_focal: bool = True,
    renderer: str = "scene",
    assume_lens: bool = False,
) -> SceneResult:
    """Draw scene ``index`` of ``seed`` as ``view`` sees it, run the pipeline (given the
    focal length with ``assume_focal``, the lens too with ``assume_lens``), compare with
    the truth."""
    image, truth = draw_scene(renderer, seed, index, obstacle_share, view)
    pipeline = Pipeline(_given(config or Config(), truth, assume_focal, assume_lens))
    return _scene_result(index, view, image, truth, pipeline)


def evaluate_video(
    seed: int,
    scenes: int,
    config: Config | None = None,
    obstacle_share: float = 0.7,
    view: View = View(),
    assume_focal: bool = False,
    renderer: str = "scene",
    mirrored: bool = False,
    done=None,
) -> list[SceneResult]:
    """Scenes ``0 … scenes − 1`` of ``seed`` as ``view`` sees them, in order (each followed
    by its mirror with ``mirrored``), through one pipeline: one camera's recording of many
    rooms, as ``companion --video`` runs it. The focal length (unless ``assume_focal``) and
    the lens are learnt across the frames; each frame's own η is compared with its truth.
    ``done()`` is called after each frame."""
    pipeline = None
    out = []
    for i in range(scenes):
        for flip in orientations(mirrored):
            seen = replace(view, mirrored=flip)
            image, truth = draw_scene(renderer, seed, i, obstacle_share, seen)
            if pipeline is None:  # every frame of a view has the same focal length
                pipeline = Pipeline(_given(config or Config(), truth, assume_focal, False))
            out.append(_scene_result(i, seen, image, truth, pipeline))
            if done:
                done()
    return out


def _given(config: Config, truth: SceneTruth, focal: bool, lens: bool) -> Config:
    """``config`` given the rendered focal length (``focal``), or the focal length and the
    lens (``lens``: the renderer's, or a pinhole for one that draws none)."""
    if not (focal or lens):
        return config
    distortion = (truth.distortion or (0.0,)) if lens else config.camera.distortion
    return replace(config, camera=replace(config.camera, focal_px=truth.focal_px,
                                          distortion=distortion))


def _scene_result(index: int, view: View, image: np.ndarray, truth: SceneTruth,
                  pipeline: Pipeline) -> SceneResult:
    """Run ``pipeline`` on one drawn frame and compare its estimate with the truth."""
    width, height = view.width, view.height
    est = pipeline(image, camera_height_m=truth.camera_height_m)

    def in_frame(points_px):
        """Pinhole pixels of the estimate → pixels of the frame, where the truth is."""
        return pipeline.frame_px(points_px, width, height)

    targets = [o for o in truth.obstacles if o.non_manhattan]
    detectable = [o for o in targets if o.detectable]
    edge_on = [o for o in targets if o.eye_level]
    target = (detectable or edge_on or targets or [None])[0]
    corner_err = range_true = None
    if targets and est.obstacles:
        matched, d = _match(in_frame(est.obstacles[0].corners_px), truth)
        if matched is not None:
            target = matched
            corner_err = d / math.hypot(width, height) * 100.0
            if est.contact is not None and matched.floor_corners:
                fc = np.array(matched.floor_corners)
                near = np.argmin(np.hypot(*(fc[:, :2] - in_frame(est.contact.pixel)[0]).T))
                range_true = float(fc[near, 2])
    return SceneResult(
        index=index,
        has_obstacle=target is not None,
        detectable=bool(detectable),
        eta_true_deg=None if target is None else target.eta_deg,
        eta_est_deg=est.eta_deg,
        corner_err_pct=corner_err,
        latency_ms=est.latency_ms,
        range_est_m=est.range_m,
        range_true_m=range_true,
        mirrored=view.mirrored,
        kind=None if target is None else target.kind,
        focal_est_px=est.focal_px,
        focal_true_px=truth.focal_px,
        eye_level=bool(edge_on) and not detectable,
        rule=est.obstacles[0].rule if est.obstacles else None,
    )


def _workers(workers: int | None) -> int:
    """Processes for a run: as asked, else the cores this process may use, at most 4."""
    return workers or min(len(os.sched_getaffinity(0)), 4)


def _pool(workers: int) -> ProcessPoolExecutor:
    return ProcessPoolExecutor(max_workers=workers, mp_context=SPAWN)


def _worker(args):
    return evaluate_scene(*args)


def drawing_order(count: int, mirrored: bool) -> list[tuple[int, bool]]:
    """The (item, mirrored) jobs of a parallel run over ``count`` scenes or clips: every
    item as drawn first, then (with ``mirrored``) every mirror. A mirror is its item's
    render flipped, so an item and its mirror side by side would have two workers path-trace
    one frame at once; in this order the mirrors read the cache. :func:`in_item_order`
    puts the results back."""
    return [(i, flip) for flip in orientations(mirrored) for i in range(count)]


def in_item_order(order: list[tuple[int, bool]], results: list) -> list:
    """``results``, one per job of ``order`` (:func:`drawing_order`) and in its order, put
    in (item, mirrored) order: each item followed by its mirror (:func:`orientations`)."""
    return [r for _, r in sorted(zip(order, results, strict=True), key=lambda pair: pair[0])]


def run_eval(
    scenes: int = 200,
    seed: int = 0,
    config: Config | None = None,
    obstacle_share: float = 0.7,
    view: View = View(),
    assume_focal: bool = True,
    workers: int | None = None,
    progress=None,
    renderer: str = "scene",
    assume_lens: bool = False,
    mirrored: bool = False,
) -> EvalReport:
    """Evaluate ``scenes`` seeded scenes as ``view`` sees them; ``progress(done, total)``
    is called as they finish. With ``mirrored``, each scene is also evaluated mirrored
    left to right, and the report pools both: twice the results, for telling a rule change
    from chance on dev. ``mirrored``, not ``view.mirrored``, decides the orientations."""
    order = drawing_order(scenes, mirrored)
    jobs = [(seed, i, config, obstacle_share, replace(view, mirrored=flip), assume_focal,
             renderer, assume_lens) for i, flip in order]
    total = len(jobs)
    workers = _workers(workers)
    results: list[SceneResult] = []
    if workers <= 1:
        for job in jobs:
            results.append(_worker(job))
            if progress:
                progress(len(results), total)
    else:
        with _pool(workers) as pool:
            for r in pool.map(_worker, jobs, chunksize=1 if renderer == "pathtraced" else 4):
                results.append(r)
                if progress:
                    progress(len(results), total)
    return EvalReport(scenes=scenes, seed=seed, results=in_item_order(order, results))


def _by_rule(f: dict) -> str:
    """``rule detections/false alarms, …`` of :meth:`EvalReport.rule_figures`, in the
    order of :data:`~companion.vision.obstacles.RULES`; ``none`` when no rule read any."""
    keys = [(r, r.replace(" ", "_")) for r in RULES]
    return ", ".join(f"{r} {f['rule_detected_' + k]}/{f['rule_false_' + k]}"
                     for r, k in keys if f"rule_detected_{k}" in f) or "none"


def format_report(report: EvalReport) -> list[str]:
    """The figures as printable lines, each with its target."""
    f = report.figures()

    def pct(x):
        return "n/a" if x is None else f"{100 * x:.1f} %"

    def deg(x):
        return "n/a" if x is None else f"{x:.2f}°"

    def mark(key, better_low=True):
        x = f[key]
        if x is None:
            return ""
        ok = x <= TARGETS[key] if better_low else x >= TARGETS[key]
        return "  ok" if ok else "  MISSED"

    return [
        f"scenes: {f['scenes']} (seed {f['seed']}), with a detectable obstacle: {f['detectable']}, "
        f"Manhattan-only: {f['manhattan_only']}, obstacle present but not detectable: "
        f"{f['not_detectable']} (η returned on {f['not_detectable_with_eta']})",
        f"η error median        {deg(f['eta_err_median_deg']):>9}   target <= 1.5°"
        + mark("eta_err_median_deg"),
        f"η error p90           {deg(f['eta_err_p90_deg']):>9}   target <= 4°"
        + mark("eta_err_p90_deg"),
        f"detection rate        {pct(f['detection_rate']):>9}   target >= 90 %"
        + mark("detection_rate", better_low=False),
        f"false-positive rate   {pct(f['false_positive_rate']):>9}   target <= 5 %"
        + mark("false_positive_rate"),
        "corner error          "
        + ("      n/a" if f["corner_err_pct"] is None else f"{f['corner_err_pct']:>7.2f} %")
        + "   target <= 8 % of the diagonal (paper: 9.98 % on LSUN)"
        + mark("corner_err_pct"),
        f"pipeline latency median {f['latency_ms_median']:.1f} ms per frame",
        f"by the rule that read the obstacle driving η, detections / false alarms: "
        f"{_by_rule(f)}",
    ]


def run_split(renderer: str, split: str, config: Config | None = None,
              workers: int | None = None, progress=None, focal_given: bool = False,
              lens_given: bool = False, mirrored: bool = False,
              eye_level: bool = False, pitch_deg: float = 0.0,
              as_video: bool = False, rug: bool = False) -> dict[str, EvalReport]:
    """One frozen split of one renderer at every camera of :data:`CAMERAS`, focal length
    not given (unless ``focal_given``, or ``lens_given``: the focal length and the lens
    distortion, diagnoses): {camera label: report}. ``mirrored``: each frame also run
    mirrored, pooled (:func:`run_eval`). ``eye_level``: the split's rooms seen from their
    rotated obstacle's height (:func:`sitl.scene.at_eye_level`). ``pitch_deg``: seen by the
    camera pitched that much further nose down. ``rug``: a rotated striped rug laid in front
    of each room's camera (:func:`sitl.scene.rug_in_view`). ``as_video``: each camera's
    frames run in order through one pipeline (:func:`evaluate_video`; not with
    ``lens_given``: the rooms' lenses differ). ``progress(done, total)`` counts frames."""
    seed, scenes = SPLITS[(renderer, split)]
    per_camera = scenes * (2 if mirrored else 1)
    total = per_camera * len(CAMERAS)
    views = {label: View(w, h, fov, eye_level=eye_level, pitch_deg=pitch_deg, rug=rug)
             for label, w, h, fov in CAMERAS}
    if as_video:
        if lens_given:
            raise ValueError("as_video learns the lens; the split's rooms each have their own")
        return _run_videos(seed, scenes, config, views, focal_given, renderer, mirrored,
                           workers, progress)
    out: dict[str, EvalReport] = {}
    for k, (label, view) in enumerate(views.items()):
        def step(done, _n, k=k):
            if progress:
                progress(k * per_camera + done, total)
        out[label] = run_eval(scenes, seed, config, view=view, assume_focal=focal_given,
                              workers=workers, progress=step, renderer=renderer,
                              assume_lens=lens_given, mirrored=mirrored)
    return out


def _video_worker(args):
    *job, queue = args
    return evaluate_video(*job, done=lambda: queue.put(1))


def _run_videos(seed: int, scenes: int, config: Config | None, views: dict[str, View],
                focal_given: bool, renderer: str, mirrored: bool, workers: int | None,
                progress) -> dict[str, EvalReport]:
    """:func:`evaluate_video` for each view, one process a view; ``progress`` counts frames."""
    total = scenes * len(orientations(mirrored)) * len(views)
    workers = min(_workers(workers), len(views))
    with SPAWN.Manager() as manager, _pool(workers) as pool:
        queue = manager.Queue()
        futures = {label: pool.submit(_video_worker, (seed, scenes, config, 0.7, view,
                                                      focal_given, renderer, mirrored, queue))
                   for label, view in views.items()}
        done = 0
        while done < total:
            try:
                done += queue.get(timeout=0.2)
            except Empty:
                if all(f.done() for f in futures.values()):  # a worker failed: its error
                    break
                continue
            if progress:
                progress(done, total)
        return {label: EvalReport(scenes=scenes, seed=seed, results=f.result())
                for label, f in futures.items()}


def _split_target(label: str) -> dict[str, float]:
    _, w, _, fov = next(c for c in CAMERAS if c[0] == label)
    return SPLIT_TARGETS[320] if w <= 320 else SPLIT_TARGETS[fov]


def format_splits(renderer: str, reports: dict[str, dict[str, EvalReport]],
                  focal_given: bool = False, lens_given: bool = False,
                  mirrored: bool = False, eye_level: bool = False,
                  pitch_deg: float = 0.0, as_video: bool = False,
                  rug: bool = False) -> list[str]:
    """One table for a renderer: a row per camera and split, issue 18's targets beside;
    then, per row, the obstacles seen at eye level, by furniture kind, and the range."""

    def pct(x):
        return "n/a" if x is None else f"{100 * x:.1f}"

    def deg(x):
        return "n/a" if x is None else f"{x:.2f}"

    given = "given (a diagnosis: the targets are without it)" if focal_given else "not given"
    if lens_given:
        given = "and lens distortion given (a diagnosis: the targets are without them)"
    if mirrored:
        given += "; each frame also mirrored left to right, the two pooled"
    if eye_level:
        given += "; each room seen from its rotated obstacle's height"
    if pitch_deg:
        given += f"; the camera pitched {pitch_deg:g}° further nose down"
    if rug:
        given += "; a rotated striped rug on the floor in front of each room's camera"
    if as_video:
        given += ("; each camera's frames run in order as one video (what it learns of its "
                  "camera carried from frame to frame), η of each frame")
    lines = [f"renderer {renderer}: focal length {given}",
             f"{'camera':<14} {'split':<5} {'seed':>5} {'det %':>6} {'η med°':>7} {'η p90°':>7} "
             f"{'FP %':>5} {'sign✗':>7} {'corner %':>8} {'f err %':>10}   targets det/med/p90"]
    # Each row's figures once, for the three blocks below.
    figures = [(label, split, by_camera[label].figures())
               for label, *_ in CAMERAS for split, by_camera in reports.items()]
    for label, split, f in figures:
        t = _split_target(label)
        miss = []
        if f["detection_rate"] is not None and f["detection_rate"] < t["detection_rate"]:
            miss.append("det")
        for key, name in (("eta_err_median_deg", "med"), ("eta_err_p90_deg", "p90")):
            if f[key] is not None and f[key] > t[key]:
                miss.append(name)
        if f["false_positive_rate"] is not None and f["false_positive_rate"] > 0.02:
            miss.append("FP")
        sign = f"{f['sign_wrong']}/{f['detected']}"
        lines.append(
            f"{label:<14} {split:<5} {f['seed']:>5} {pct(f['detection_rate']):>6} "
            f"{deg(f['eta_err_median_deg']):>7} {deg(f['eta_err_p90_deg']):>7} "
            f"{pct(f['false_positive_rate']):>5} {sign:>7} "
            f"{'n/a' if f['corner_err_pct'] is None else format(f['corner_err_pct'], '.2f'):>8}"
            f" {pct(f['focal_err_median']) + '/' + pct(f['focal_err_p90']):>10}"
            f"   >={100 * t['detection_rate']:.0f}/<={t['eta_err_median_deg']:g}/"
            f"<={t['eta_err_p90_deg']:g}" + (f"  MISSED {','.join(miss)}" if miss else "  ok"))
    lines.append("seen at eye level (the top edge-on, along the horizon; not in det %): "
                 "detected / n, η median / p90, sign✗:")
    for label, split, f in figures:
        if f["eye_level"]:
            lines.append(
                f"  {label:<14} {split:<5} {f['eye_level_detected']}/{f['eye_level']} "
                f"({pct(f['eye_level_detection_rate'])} %), "
                f"{deg(f['eye_level_eta_err_median_deg'])}° / "
                f"{deg(f['eye_level_eta_err_p90_deg'])}°, {f['eye_level_sign_wrong']}")
        else:
            lines.append(f"  {label:<14} {split:<5} none")
    lines.append("f err: relative error of the focal length each frame rested on, median / "
                 "p90; detected / detectable by obstacle kind:")
    for label, split, f in figures:
        kinds = sorted(k.removeprefix("detectable_") for k in f if k.startswith("detectable_"))
        lines.append(f"  {label:<14} {split:<5} " + ", ".join(
            f"{k} {f['detected_' + k]}/{f['detectable_' + k]}" for k in kinds))
    lines.append("η returned, by the rule that read the obstacle driving it: detections / "
                 "false alarms:")
    for label, split, f in figures:
        lines.append(f"  {label:<14} {split:<5} {_by_rule(f)}")
    lines.append("range to the obstacle's floor contact (camera height given), relative error "
                 "median / p90, measured, too far by > 20 %:")
    for label, split, f in figures:
        parts = []
        for lo, hi in RANGE_BANDS:
            key = f"range_{lo:g}_{hi:g}m"
            if f[f"{key}_n"]:
                parts.append(f"{lo:g}–{hi:g} m {100 * f[key + '_rel_err_median']:.1f} / "
                             f"{100 * f[key + '_rel_err_p90']:.1f} %, n {f[key + '_n']}, "
                             f"too far {f[key + '_too_far']}")
            else:
                parts.append(f"{lo:g}–{hi:g} m n 0")
        lines.append(f"  {label:<14} {split:<5} " + "; ".join(parts))
    return lines


CLIPS = {
    ("scene", "dev"): (0, 40),
    ("scene", "test"): (9001, 40),
    ("pathtraced", "dev"): (21, 12),
    ("pathtraced", "test"): (9021, 12),
}
"""(seed, clips) of each renderer's frozen tracking splits. Never tune on ``test``."""

LONG_CLIPS = {
    ("scene", "dev"): (30, 20),
    ("scene", "test"): (9030, 20),
    ("pathtraced", "dev"): (31, 8),
    ("pathtraced", "test"): (9031, 8),
}
"""(seed, clips) of the long clips (:data:`LONG_CLIP_FRAMES` frames): long enough for a
video to learn its lens (``pipeline.LENS_FRAMES``) and fly on with it undone."""

LONG_CLIP_FRAMES = 24
LATE_FRAME = 12
"""long clips are also scored on their frames from this one on: after the lens is learnt"""

CLIP_FRAMES = 10
CLIP_FPS = 10.0
"""frame rate of a clip: the yaw between frames makes the motion blur within one"""


@dataclass(frozen=True)
class FrameResult:
    clip: int
    frame: int
    has_obstacle: bool
    detectable: bool
    eta_true_deg: float | None
    eta_deg: float | None
    eta_tracked_deg: float | None
    mirrored: bool = False  # the clip was mirrored left to right (sitl.scene.mirror)


CLIP_CACHE = "clips-2"
"""The cache folder of path-traced clip frames. 2: a clip's textures stay from frame to
frame (the older frames, in ``clips``, drew the floor, walls and furniture afresh each
frame)."""


def evaluate_clip(seed: int, clip: int, config: Config | None = None,
                  obstacle_share: float = 0.7, frames: int = CLIP_FRAMES,
                  renderer: str = "scene", mirrored: bool = False) -> list[FrameResult]:
    """A clip: a random room seen while the vehicle yaws at a steady 1–4° per frame either
    way and drifts forward; one pipeline runs over its frames, focal length not given, as
    on a video. ``scene`` clips have a 90° lens; ``pathtraced`` ones the renderer's own
    50–110°, with the motion blur of the clip's yaw rate at :data:`CLIP_FPS`. ``mirrored``:
    every frame mirrored left to right, the clip of the reflected room yawing the other
    way (:func:`sitl.scene.mirror`)."""
    from sitl.scene import yaw_sweep

    rng = np.random.default_rng([seed, clip])
    has_obstacle = bool(rng.random() < obstacle_share)
    if renderer == "scene":
        scene, cam = random_scene(rng, 640, 480, obstacle=has_obstacle, hfov_deg=90.0)
    else:
        from sitl import pathtraced

        r3, cam = pathtraced.random_room(rng, 640, 480, obstacle=has_obstacle)
    rate = float(rng.uniform(1.0, 4.0) * rng.choice([-1, 1]))
    start = cam.yaw_deg - rate * frames / 2
    pipe = Pipeline(config or Config())
    out = []
    for k, c in enumerate(yaw_sweep(cam, start, start + rate * (frames - 1), frames,
                                    advance_m=float(rng.uniform(0.0, 0.6)))):
        if renderer == "scene":
            image, truth = render(scene, c, frame=k + 1)  # a video's noise, frame by frame
        else:
            # A video's noise is drawn afresh each frame; its textures stay (Look.frame).
            look = replace(r3.look, frame=k + 1, yaw_rate_deg_s=rate * CLIP_FPS)
            image, truth = _render_cached(f"{CLIP_CACHE}/{seed}-{clip}-{k}.png",
                                          replace(r3, look=look), c)
        if mirrored:
            image, truth = mirror(image, truth)
        est = pipe(image)
        targets = [o for o in truth.obstacles if o.non_manhattan]
        detectable = [o for o in targets if o.detectable]
        target = (detectable or targets or [None])[0]
        if targets and est.obstacles:
            corners = pipe.frame_px(est.obstacles[0].corners_px, image.shape[1], image.shape[0])
            target = _match(corners, truth)[0] or target
        out.append(FrameResult(clip, k, bool(targets), bool(detectable),
                               None if target is None else target.eta_deg,
                               est.eta_deg, est.eta_tracked_deg, mirrored))
    return out


def _clip_worker(args):
    return evaluate_clip(*args)


def run_clips(split: str, config: Config | None = None, workers: int | None = None,
              progress=None, renderer: str = "scene", long: bool = False,
              mirrored: bool = False) -> list[FrameResult]:
    """Every clip of a renderer's frozen tracking split (:data:`CLIPS`, or with ``long``
    :data:`LONG_CLIPS`); with ``mirrored`` each clip also mirrored, the two pooled."""
    seed, clips = (LONG_CLIPS if long else CLIPS)[(renderer, split)]
    length = LONG_CLIP_FRAMES if long else CLIP_FRAMES
    workers = _workers(workers)
    order = drawing_order(clips, mirrored)
    by_clip: list[list[FrameResult]] = []
    with _pool(workers) as pool:
        jobs = [(seed, i, config, 0.7, length, renderer, flip) for i, flip in order]
        for frames in pool.map(_clip_worker, jobs):
            by_clip.append(frames)
            if progress:
                progress(len(by_clip), len(jobs))
    return [r for frames in in_item_order(order, by_clip) for r in frames]


def late_frames(frames: list[FrameResult]) -> list[FrameResult]:
    """The frames of long clips from :data:`LATE_FRAME` on: after the lens is learnt."""
    return [r for r in frames if r.frame >= LATE_FRAME]


def clip_figures(frames: list[FrameResult], tracked: bool) -> dict[str, float | int | None]:
    """Per-frame (``tracked`` False) or tracked figures over a split's frames."""
    def eta(r):
        return r.eta_tracked_deg if tracked else r.eta_deg

    det = [r for r in frames if r.detectable]
    hits = [r for r in det if eta(r) is not None]
    # A tracked η may follow the OVP 90° from the truth's M (eq. 9 held across a flip), so
    # both are compared modulo 90°: the error is to the nearest face.
    err = np.array([abs((eta(r) - r.eta_true_deg + 45.0) % 90.0 - 45.0) for r in hits])
    # A turn the wrong way, where the truth is clear: near 45° either face is a fair answer.
    signed = [r for r in hits if 1.0 <= abs(r.eta_true_deg) <= 40.0]
    wrong = [r for r in signed if np.sign(eta(r)) != np.sign(r.eta_true_deg)]
    clean = [r for r in frames if not r.has_obstacle]
    fps = [r for r in clean if eta(r) is not None]
    return {
        "frames": len(frames),
        "detectable": len(det),
        "detection_rate": len(hits) / len(det) if det else None,
        "eta_err_median_deg": float(np.median(err)) if len(err) else None,
        "eta_err_p90_deg": float(np.percentile(err, 90)) if len(err) else None,
        "sign_wrong": len(wrong),
        "signed": len(signed),
        "false_positive_rate": len(fps) / len(clean) if clean else None,
    }


def format_clips(by_split: dict[str, list[FrameResult]], renderer: str = "scene",
                 long: bool = False, mirrored: bool = False) -> list[str]:
    lens = "90° lens" if renderer == "scene" else "50–110° lenses"
    n = LONG_CLIP_FRAMES if long else CLIP_FRAMES
    lines = [f"tracking, renderer {renderer}, {lens}, focal length not given: "
             f"{n}-frame yawing clips; η error modulo 90° (to the nearest face), "
             "sign✗ where 1° <= |η_truth| <= 40°"
             + (f"; 'late': frames {LATE_FRAME}–{n - 1}, the lens learnt" if long else "")
             + ("; each clip also mirrored left to right, the two pooled" if mirrored else ""),
             f"{'split':<5} {'η':<15} {'det %':>6} {'η med°':>7} {'η p90°':>7} {'FP %':>5} "
             f"{'sign✗':>8}"]
    rows = [("per frame", False, False), ("tracked", True, False)]
    if long:
        rows += [("late, per frame", False, True), ("late, tracked", True, True)]
    for split, frames in by_split.items():
        for name, tracked, late in rows:
            f = clip_figures(late_frames(frames) if late else frames, tracked)

            def num(x, scale=1.0, fmt=".2f"):
                return "n/a" if x is None else format(scale * x, fmt)
            lines.append(
                f"{split:<5} {name:<15} {num(f['detection_rate'], 100, '.1f'):>6} "
                f"{num(f['eta_err_median_deg']):>7} {num(f['eta_err_p90_deg']):>7} "
                f"{num(f['false_positive_rate'], 100, '.1f'):>5} "
                f"{str(f['sign_wrong']) + '/' + str(f['signed']):>8}")
    return lines


if __name__ == "__main__":  # pragma: no cover - handy during development
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 40
    rep = run_eval(n, seed=int(sys.argv[2]) if len(sys.argv) > 2 else 0)
    print("\n".join(format_report(rep)))

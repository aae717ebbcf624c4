"""``companion bench``: how long every stage takes, against the line detectors alone.

For each resolution, seeded rendered scenes are encoded into an MP4 (OpenCV's writer), then
decoded and run through the pipeline ``--repeat`` times. On the same decoded frames, in the
same run, the configured line detector alone and OpenCV's LSD alone are timed (grey image
in, segments out), so their ratios to the pipeline come from one run on one machine.
``total`` is the pipeline from a decoded frame to η (lines, VPs, corners, obstacles,
heading); decoding is shown apart. The timing runs in a child process that only decodes
and runs the pipeline, so its peak RSS is the pipeline's, not the renderer's.

Frame-to-setpoint latency: the 640×480 frames are fed to the real offboard controller
(MAVSDK) flying the mock autopilot over UDP on 127.0.0.1; each sample is the time from the
frame's capture timestamp (just before decoding) to the mock receiving the setpoint that
carries the frame's new yaw rate.
"""

from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from companion.config import Config
from companion.control.policy import decide_turn
from companion.vision.lines import make_detector, to_gray
from companion.vision.pipeline import STAGES, Pipeline
from sitl.scene import random_scene, render
from sitl.workers import SPAWN

__all__ = ["add_arguments", "bench", "RESOLUTIONS"]

RESOLUTIONS = ((320, 240), (640, 480), (1280, 720), (1920, 1080))
HFOV_DEG = 80.0  # random_scene's cameras; the pipeline is given this focal length


BENCH_CAMERA_HEIGHT_M = 1.0
"""m: the height the pipeline is given, so that ``heading`` includes the floor-plane
ranging it does in flight (the value does not change the cost)"""

def _write_video(path: Path, width: int, height: int, frames: int, seed: int) -> float:
    """Render ``frames`` seeded scenes at width×height into an MP4; returns their focal length."""
    rng = np.random.default_rng(seed)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (width, height))
    focal = 0.0
    try:
        for _ in range(frames):
            scene, cam = random_scene(rng, width, height)
            image, truth = render(scene, cam, supersample=1)
            focal = truth.focal_px
            writer.write(image)
    finally:
        writer.release()
    return focal


def _stats(values: list[float]) -> dict[str, float]:
    v = np.asarray(values, dtype=float)
    return {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)),
            "p99": float(np.percentile(v, 99))}


def _time_resolution(video: str, focal_px: float | None, repeat: int,
                     config: Config) -> dict:
    """Child process: decode, then the pipeline, the detector alone and LSD alone on every
    frame (grey image in, segments out for the two detectors)."""
    cfg = replace(config, camera=replace(config.camera, focal_px=focal_px))
    pipeline = Pipeline(cfg)
    rows: dict[str, list[float]] = {k: [] for k in ("decode", *STAGES, "total",
                                                    "detector", "lsd", "segments")}
    detector = lsd = None
    cap = cv2.VideoCapture(video)
    ok, first = cap.read()
    cap.release()
    if ok:  # first-call costs (allocations, lazy imports) are not per-frame costs
        pipeline(first)
        detector, _ = pipeline.detector_for(first.shape[1], first.shape[0])
        lsd = make_detector("lsd", 0.0)
    runs = 0
    for _ in range(repeat):
        cap = cv2.VideoCapture(video)
        while True:
            t0 = time.perf_counter()
            ok, frame = cap.read()
            t1 = time.perf_counter()
            if not ok:
                break
            rows["decode"].append((t1 - t0) * 1e3)
            gray = to_gray(frame)
            # The three run in turns, each first on every third frame: whichever runs
            # right after decoding finds a colder cache (~0.1–0.2 ms at 640×480).
            for k in range(3):
                which = (runs + k) % 3
                if which == 0:
                    # With a camera height, as the service runs in flight (the
                    # autopilot's altitude): the heading stage then ranges too.
                    est = pipeline(frame, camera_height_m=BENCH_CAMERA_HEIGHT_M)
                    for stage in STAGES:
                        rows[stage].append(est.stage_ms[stage])
                    rows["total"].append(est.latency_ms)
                    rows["segments"].append(float(len(est.segments)))
                else:
                    t2 = time.perf_counter()
                    (detector if which == 1 else lsd)(gray)
                    rows["detector" if which == 1 else "lsd"].append(
                        (time.perf_counter() - t2) * 1e3)
            runs += 1
        cap.release()
    out = {k: _stats(v) for k, v in rows.items()}
    out["frames"] = len(rows["total"])
    out["peak_rss_mb"] = _peak_rss_mb()
    return out


def _peak_rss_mb() -> float:
    """This process's peak resident set, MB. VmHWM, not getrusage's ru_maxrss: Linux carries
    the forking parent's peak into ru_maxrss across exec, and the parent rendered scenes."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _setpoint_latency(video: str, focal_px: float, repeat: int, config: Config,
                      port: int) -> list[float]:
    """Capture → setpoint at the mock, ms, for every frame whose yaw rate changed."""
    from companion.control.offboard import OffboardController
    from sitl.closed_loop import fly_alongside, hovering_autopilot, sitl_link

    cfg = sitl_link(replace(config, camera=replace(config.camera, focal_px=focal_px)), port,
                    stale_after_s=2.0, forward_speed_m_s=0.0)  # hover: each frame's own rate
    pipeline = Pipeline(cfg)
    controller = OffboardController(cfg)
    samples: list[tuple[float, float]] = []  # (capture t, yaw rate)
    latencies: list[float] = []
    with hovering_autopilot(port) as mock:

        def camera() -> None:
            frames = _frames(video)
            warm_up = decide_turn(pipeline(frames[0]).eta_deg, cfg.policy)
            deadline = time.monotonic() + 15.0  # engaging: the first frames are warm-up
            while controller.state.name != "active" and time.monotonic() < deadline:
                controller.submit(warm_up)
                time.sleep(0.05)
            last_rate = None
            for frame in frames * repeat:
                if controller.state.name != "active":
                    return
                t_cap = time.monotonic()
                est = pipeline(frame)
                cmd = decide_turn(est.eta_deg, cfg.policy, est.scene_understood)
                controller.submit(cmd, est.eta_deg, t_s=t_cap)
                if last_rate is not None and abs(cmd.yaw_rate_deg_s - last_rate) > 1e-3:
                    samples.append((t_cap, cmd.yaw_rate_deg_s))
                last_rate = cmd.yaw_rate_deg_s
                time.sleep(0.1)  # a 10 Hz camera: every setpoint settles before the next

        fly_alongside(controller, camera, linger_s=0.2)
        received = list(mock.setpoints)
    for t_cap, rate in samples:
        hit = next((s.t_s for s in received
                    if s.t_s >= t_cap and abs(s.yaw_rate_deg_s - rate) < 1e-3), None)
        if hit is not None:
            latencies.append((hit - t_cap) * 1e3)
    return latencies


def _frames(video: str) -> list[np.ndarray]:
    cap = cv2.VideoCapture(video)
    out = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        out.append(frame)
    cap.release()
    return out


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of ``companion bench``."""
    ap.add_argument("--frames", type=int, default=20,
                    help="distinct rendered scenes per resolution (default 20)")
    ap.add_argument("--repeat", type=int, default=5,
                    help="passes over them (default 5: 100 timed frames per resolution)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--resolutions", nargs="+", default=[f"{w}x{h}" for w, h in RESOLUTIONS],
                    metavar="WxH")
    ap.add_argument("--no-focal", action="store_true",
                    help="do not give the focal length (measures self-calibration)")
    ap.add_argument("--no-sitl", action="store_true", help="skip the SITL latency run")
    ap.add_argument("--latency-frames", type=int, default=200,
                    help="frames fed to SITL at 10 Hz for frame → setpoint (default 200; "
                         "samples are the frames whose yaw rate changed)")
    ap.add_argument("--port", type=int, default=14562, help="UDP port for the SITL run")
    ap.add_argument("--config", metavar="PATH", dest="bench_config", help="YAML config")
    ap.add_argument("--json", metavar="PATH", help="also write the figures as JSON")


def _parse_resolution(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--resolutions {text!r}: expected WxH, e.g. 640x480") from None
    if w < 64 or h < 48:
        raise ValueError(f"--resolutions {text!r}: too small")
    return w, h


def bench(args: argparse.Namespace, config: Config | None = None) -> int:
    cfg = config or Config()
    if args.frames < 1 or args.repeat < 1 or args.latency_frames < 1:
        raise ValueError("--frames, --repeat and --latency-frames must be at least 1")
    sizes = [_parse_resolution(r) for r in args.resolutions]
    figures: dict = {"resolutions": {}}
    with tempfile.TemporaryDirectory() as tmp:
        videos = {}
        for w, h in sizes:
            path = Path(tmp) / f"bench_{w}x{h}.mp4"
            print(f"rendering {args.frames} scenes at {w}×{h} …", flush=True)
            focal = _write_video(path, w, h, args.frames, args.seed)
            videos[(w, h)] = (str(path), focal)
        for (w, h), (video, focal) in videos.items():
            with SPAWN.Pool(1) as pool:  # a fresh process per resolution: its own peak RSS
                res = pool.apply(_time_resolution,
                                 (video, None if args.no_focal else focal, args.repeat, cfg))
            figures["resolutions"][f"{w}x{h}"] = res
        if not args.no_sitl and (640, 480) in videos:
            video, focal = videos[(640, 480)]
            passes = -(-args.latency_frames // args.frames)  # ceil: whole passes over the video
            lat = _setpoint_latency(video, focal, passes, cfg, args.port)
            figures["frame_to_setpoint_ms"] = _stats(lat) if lat else None
            figures["frame_to_setpoint_samples"] = len(lat)
    _print(figures, args)
    if args.json:
        flat = {}
        for name, r in figures["resolutions"].items():
            flat[name] = {"total_ms_median": r["total"]["median"],
                          "total_ms_p99": r["total"]["p99"],
                          "detector_ms_median": r["detector"]["median"],
                          "lsd_ms_median": r["lsd"]["median"], "peak_rss_mb": r["peak_rss_mb"],
                          "stages": {k: r[k] for k in ("decode", *STAGES, "total", "detector",
                                                       "lsd")},
                          "segments_median": r["segments"]["median"], "frames": r["frames"]}
        out = {"resolutions": flat,
               "frame_to_setpoint_ms": figures.get("frame_to_setpoint_ms"),
               "frame_to_setpoint_samples": figures.get("frame_to_setpoint_samples")}
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=2))
    return 0


def _print(figures: dict, args: argparse.Namespace) -> None:
    cols = ("decode", *STAGES, "total", "detector", "lsd")
    focal = "focal estimated" if args.no_focal else "focal given"
    print(f"\nms per frame, median / p95 / p99 ({focal}; "
          "camera height given; total = lines+vps+corners+obstacles+heading)")
    print(f"{'':>10}" + "".join(f"{c:>20}" for c in cols))
    for name, r in figures["resolutions"].items():
        print(f"{name:>10}" + "".join(
            f"{r[c]['median']:>8.2f}/{r[c]['p95']:>5.1f}/{r[c]['p99']:>5.1f}" for c in cols))
    print(f"\n{'':>10}{'total/detector':>16}{'total/LSD':>11}{'p99/median':>12}"
          f"{'segments':>10}{'peak RSS':>10}{'frames':>8}")
    base = None
    for name, r in figures["resolutions"].items():
        t = r["total"]
        print(f"{name:>10}{t['median'] / r['detector']['median']:>15.2f}×"
              f"{t['median'] / r['lsd']['median']:>10.2f}×{t['p99'] / t['median']:>11.2f}×"
              f"{r['segments']['median']:>10.0f}{r['peak_rss_mb']:>8.0f} MB{r['frames']:>8}")
        w, h = (int(v) for v in name.split("x"))
        if base is None:
            base = (w * h, t["median"])
        else:
            print(f"{'':>10}  total ×{t['median'] / base[1]:.2f} for pixels "
                  f"×{w * h / base[0]:.2f} (against the first resolution)")
    lat = figures.get("frame_to_setpoint_ms")
    if lat:
        print(f"\nframe → setpoint at the mock autopilot (640×480, SITL, "
              f"{figures['frame_to_setpoint_samples']} samples): median {lat['median']:.1f} ms, "
              f"p95 {lat['p95']:.1f} ms, p99 {lat['p99']:.1f} ms")

"""The public CLI, run as a real process on real encoded videos."""

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import pytest

from companion.report import LOG_KEYS
from sitl.sample import sample_scene

ROOT = Path(__file__).resolve().parents[1]
EXE = [sys.executable, "-m", "companion.cli"]


def run(*args, timeout=120):
    return subprocess.run(
        [*EXE, *map(str, args)], capture_output=True, text=True, timeout=timeout, cwd=ROOT
    )


def read_log(path):
    return [json.loads(line) for line in Path(path).read_text().splitlines()]


def test_dry_run_writes_exact_log_records(sample_video, tmp_path):
    video, truth_path = sample_video
    log = tmp_path / "log.jsonl"
    r = run("--video", video, "--dry-run", "--log", log, "--no-progress")
    assert r.returncode == 0, r.stderr
    records = read_log(log)
    truth = [json.loads(line) for line in truth_path.read_text().splitlines()]
    assert len(records) == len(truth) == 6
    for i, (rec, tru) in enumerate(zip(records, truth, strict=True)):
        assert tuple(rec) == LOG_KEYS
        assert rec["frame"] == i
        assert rec["t"] == pytest.approx(i / 10.0)
        assert rec["action"] in {"left", "right", "forward", "hold"}
        # The box is to the right of the heading in every frame: turn right.
        assert tru["obstacles"][0]["eta_deg"] > 0
        if rec["eta_deg"] is not None:
            assert rec["eta_deg"] > 0
            assert rec["yaw_rate_deg_s"] > 0
            assert rec["action"] == "right"
    assert sum(rec["eta_deg"] is not None for rec in records) >= 5
    assert "frames: 6" in r.stdout
    assert "latency: median" in r.stdout
    # Six frames are too few to learn the lens from: the summary says so.
    assert "lens: not learnt, 6 of the 9 frames it needs" in r.stdout
    # The focal length learnt: the sample's 80° lens, steady enough to give from frame 1.
    told = re.search(r"focal length: (\d+) px \(80° across\).*steady: --focal-px (\d+)",
                     r.stdout)
    assert told and told[1] == told[2] and abs(int(told[1]) / sample_scene()[1].focal_px - 1) < 0.02
    assert "Traceback" not in r.stderr


def test_the_summary_gives_the_p95_after_the_frames_that_learnt_the_lens():
    # A video's first frames also search the lens, at about three times the lines stage's
    # cost; on a short recording they are its p95, so the steady one is told beside it.
    from types import SimpleNamespace

    from companion.config import CameraConfig, Config
    from companion.report import Summary
    from companion.vision.pipeline import Pipeline

    assert Pipeline(Config()).learning_lens
    assert not Pipeline(Config(camera=CameraConfig(focal_px=500.0, distortion=(0.0,))
                               )).learning_lens
    frame = SimpleNamespace(eta_deg=None)
    summary = Summary()
    for k in range(40):
        summary.add(frame, 30.0 if k < 9 else 5.0, learning_lens=k < 9)
    line = summary.lines(1.0)[1]
    assert "p95 30.0 ms (5.0 ms after the 9 frames that learnt the lens)" in line, line
    steady = Summary()
    for k in range(40):
        steady.add(frame, 5.0 + 0.1 * k)
    assert "after the" not in steady.lines(1.0)[1]


def test_focal_px_is_reported_and_used(sample_video, tmp_path):
    video, _ = sample_video
    log_a, log_b = tmp_path / "a.jsonl", tmp_path / "b.jsonl"
    assert run("--video", video, "--dry-run", "--log", log_a).returncode == 0
    r = run("--video", video, "--dry-run", "--log", log_b, "--focal-px", "640")
    assert "focal 640 px (given)" in r.stdout
    a = [x["eta_deg"] for x in read_log(log_a) if x["eta_deg"] is not None]
    b = [x["eta_deg"] for x in read_log(log_b) if x["eta_deg"] is not None]
    # A longer D of eq. 10 gives smaller angles of the same sign.
    assert a and b and max(b) < max(a)


def test_annotate_writes_every_frame(sample_video, tmp_path):
    video, _ = sample_video
    out = tmp_path / "ann.mp4"
    r = run("--video", video, "--dry-run", "--annotate", out)
    assert r.returncode == 0, r.stderr
    cap = cv2.VideoCapture(str(out))
    frames = 0
    while cap.read()[0]:
        frames += 1
    assert frames == 6


def test_a_calibrated_lens_runs_and_annotates_the_pinhole_picture(sample_video, tmp_path):
    video, _ = sample_video
    cfg = tmp_path / "lens.yaml"
    cfg.write_text("camera:\n  focal_px: 381\n  distortion: [-0.05, 0.01]\n")
    out, log = tmp_path / "ann.mp4", tmp_path / "log.jsonl"
    r = run("--video", video, "--dry-run", "--config", cfg, "--annotate", out, "--log", log)
    assert r.returncode == 0, r.stderr
    assert "focal 381 px (given), lens distortion undone" in r.stdout
    assert len(read_log(log)) == 6
    cap = cv2.VideoCapture(str(out))
    ok, first = cap.read()
    assert ok and first.shape[:2] == (480, 640)
    # [0] declares a pinhole: nothing is undone, and the header says so.
    cfg.write_text("camera:\n  focal_px: 381\n  distortion: [0]\n")
    r = run("--video", video, "--dry-run", "--config", cfg)
    assert r.returncode == 0, r.stderr
    assert "focal 381 px (given), a pinhole lens (nothing undone)" in r.stdout
    assert "distortion undone" not in r.stdout
    # Without the focal length the coefficients mean nothing: refused in one line.
    cfg.write_text("camera:\n  distortion: [-0.05]\n")
    _assert_one_line_error(run("--video", video, "--dry-run", "--config", cfg),
                           "camera.distortion needs camera.focal_px")


def test_blank_video_holds(blank_video, tmp_path):
    log = tmp_path / "log.jsonl"
    assert run("--video", blank_video, "--dry-run", "--log", log).returncode == 0
    recs = read_log(log)
    assert recs and all(r["action"] == "hold" and r["yaw_rate_deg_s"] == 0 for r in recs)


def _assert_one_line_error(r, needle):
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert lines[-1].startswith("companion: error: "), r.stderr
    assert needle in lines[-1]
    assert "Traceback" not in r.stderr


def test_missing_file(tmp_path):
    _assert_one_line_error(run("--video", tmp_path / "nope.mp4", "--dry-run"), "video not found")


def test_zero_byte_file(tmp_path):
    p = tmp_path / "empty.mp4"
    p.write_bytes(b"")
    _assert_one_line_error(run("--video", p, "--dry-run"), "empty (0 bytes)")


def test_text_file_named_mp4(tmp_path):
    p = tmp_path / "notes.mp4"
    p.write_text("this is not a video\n" * 50)
    _assert_one_line_error(run("--video", p, "--dry-run"), "not a video OpenCV can decode")


def test_a_camera_given_as_a_recording_points_to_the_service():
    # A live camera has no end and no file: `companion run --source` reads it.
    for camera in ("/dev/video0", "0"):
        _assert_one_line_error(run("--video", camera, "--dry-run"),
                               f"`companion run --source {camera}`")


def test_empty_folder(tmp_path):
    _assert_one_line_error(run("--video", tmp_path, "--dry-run"), "no images in folder")


def test_image_folder_in_name_order_with_vps_and_focal(sample_video, tmp_path):
    video, _ = sample_video
    cap = cv2.VideoCapture(str(video))
    folder = tmp_path / "frames"
    folder.mkdir()
    for name in ("frame_b.png", "frame_a.jpg", "frame_c.png"):
        ok, image = cap.read()
        assert ok
        cv2.imwrite(str(folder / name), image)
    cap.release()
    (folder / "README.txt").write_text("not an image")
    log = tmp_path / "folder.jsonl"
    result = run("--video", folder, "--dry-run", "--log", log, "--focal-px", "381")
    assert result.returncode == 0, result.stderr
    assert "skipping README.txt: not an image" in result.stderr
    records = [json.loads(line) for line in log.read_text().splitlines()]
    assert [r["source"] for r in records] == ["frame_a.jpg", "frame_b.png", "frame_c.png"]
    for r in records:
        assert r["focal_px"] == 381.0
        v1, v2, v3 = r["layout_vps"]
        assert v3 is not None and len(v3) == 3 and v3[2] in (0.0, 1.0)
        assert v1 is not None  # the sample's room shows its layout


def test_unreadable_and_bad_configs(sample_video, tmp_path):
    video, _ = sample_video
    _assert_one_line_error(
        run("--video", video, "--dry-run", "--config", tmp_path / "none.yaml"),
        "config file not found",
    )
    bad = tmp_path / "bad.yaml"
    bad.write_text("policy:\n  max_turn: 10\n")
    _assert_one_line_error(
        run("--video", video, "--dry-run", "--config", bad), "unknown key 'policy.max_turn'"
    )
    if os.geteuid() != 0:  # root reads anything
        locked = tmp_path / "locked.yaml"
        locked.write_text("policy: {}\n")
        locked.chmod(0)
        _assert_one_line_error(
            run("--video", video, "--dry-run", "--config", locked), "cannot read config"
        )


def test_a_config_before_the_command_is_the_commands_config(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("policy:\n  max_turn: 10\n")
    # Read, not silently ignored: its bad key is the error, for every command.
    for command in ("eval", "bench", "run"):
        _assert_one_line_error(run("--config", bad, command), "unknown key 'policy.max_turn'")
    _assert_one_line_error(run("--config", bad, "sim", "--scenario", "approach", "--runs", "1"),
                           "unknown key 'policy.max_turn'")
    _assert_one_line_error(run("--config", bad, "sim"), "--config goes with --scenario approach")
    other = tmp_path / "other.yaml"
    other.write_text("policy: {}\n")
    _assert_one_line_error(run("--config", other, "eval", "--config", bad), "two configs given")
    _assert_one_line_error(run("--log", tmp_path / "x.jsonl", "eval"),
                           "--log goes with `companion --video FILE --dry-run`")
    _assert_one_line_error(run("--focal-px", "300", "--dry-run", "bench"),
                           "--dry-run, --focal-px go with")
    _assert_one_line_error(run("--video", "flight.mp4", "run"), "companion run --source FILE")


def test_video_without_dry_run_refuses(sample_video):
    _assert_one_line_error(run("--video", sample_video[0]), "needs --dry-run")


def test_nothing_to_do():
    _assert_one_line_error(run(), "nothing to do")


def test_ctrl_c_keeps_what_was_written(tmp_path):
    # A longer real video so that the run is still going when SIGINT arrives.
    from sitl.sample import sample_scene
    from sitl.scene import write_video, yaw_sweep

    scene, cam = sample_scene()
    video = tmp_path / "long.mp4"
    write_video(scene, yaw_sweep(cam, 0.0, 30.0, 3), video, 10.0)
    # Loop the 3 frames into a long file cheaply by re-writing them.
    cap = cv2.VideoCapture(str(video))
    frames = [f for ok, f in iter(lambda: cap.read(), (False, None)) if ok]
    long = tmp_path / "longer.mp4"
    w = cv2.VideoWriter(str(long), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (640, 480))
    for i in range(400):
        w.write(frames[i % 3])
    w.release()
    log = tmp_path / "log.jsonl"
    p = subprocess.Popen(
        [*EXE, "--video", str(long), "--dry-run", "--log", str(log)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # A shell starts background jobs with SIGINT ignored, and a child inherits that:
        # Python then never raises KeyboardInterrupt. A user's Ctrl-C reaches a terminal's
        # foreground job, so the run under test gets the default, whoever started pytest.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and (not log.exists() or log.stat().st_size < 300):
        time.sleep(0.05)
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=30)
    assert p.returncode == 130, err
    assert "Traceback" not in err
    recs = read_log(log)  # every line is complete JSON
    assert 1 <= len(recs) < 400
    assert "frames:" in out


def test_eval_prints_figures(tmp_path):
    js = tmp_path / "fig.json"
    cfg = tmp_path / "c.yaml"
    cfg.write_text("vision: {obstacles: {hidden_edge_corners: false}}\n")
    r = run("eval", "--scenes", "3", "--workers", "1", "--json", js, "--config", cfg,
            timeout=300)
    assert r.returncode == 0, r.stderr
    # The closing line is the command that measures the same again, config included.
    assert r.stdout.splitlines()[-1].endswith(
        f" s; companion eval --scenes 3 --seed 0 --config {cfg})")
    for name in ("η error median", "detection rate", "false-positive rate", "corner error",
                 "by the rule that read the obstacle driving η"):
        assert name in r.stdout
    fig = json.loads(js.read_text())
    assert fig["scenes"] == 3
    assert fig["detectable"] + fig["manhattan_only"] + fig["not_detectable"] == 3


def test_eval_writes_frames_and_diff_lists_the_frames_that_changed(tmp_path):
    old = tmp_path / "old.jsonl"
    r = run("eval", "--scenes", "4", "--workers", "1", "--frames", old, timeout=300)
    assert r.returncode == 0, r.stderr
    rows = read_log(old)
    assert [row["index"] for row in rows] == [0, 1, 2, 3]
    assert {row["camera"] for row in rows} == {"640×480"}
    same = run("eval", "--diff", old, old)
    assert same.returncode == 0, same.stderr
    assert same.stdout.splitlines() == [
        "4 frames in both runs; 0 changed (an η error that moved by more than 1° counts)"]
    # One Manhattan-only frame given an η it did not have: a false alarm, named.
    k = next(i for i, row in enumerate(rows) if not row["has_obstacle"])
    rows[k]["eta_est_deg"] = 12.5 if rows[k]["eta_est_deg"] is None else None
    what = "false alarm" if rows[k]["eta_est_deg"] is not None else "false alarm gone"
    new = tmp_path / "new.jsonl"
    new.write_text("".join(json.dumps(row) + "\n" for row in rows))
    d = run("eval", "--diff", old, new)
    assert d.returncode == 0, d.stderr
    lines = d.stdout.splitlines()
    assert lines[0].startswith("4 frames in both runs; 1 changed")
    assert lines[1] == f"640×480, scene seed 0: 1 {what}"
    assert lines[2].split()[0] == str(rows[k]["index"]) and what in lines[2]
    _assert_one_line_error(run("eval", "--diff", old, tmp_path / "none.jsonl"),
                           "frames file not found")
    (tmp_path / "fig.json").write_text('{"scenes": 4}\n')
    _assert_one_line_error(run("eval", "--diff", old, tmp_path / "fig.json"),
                           "not a frame row")
    _assert_one_line_error(run("eval", "--renderer", "scene", "--clips", "--frames", new),
                           "--frames goes with --scenes or --renderer")


def test_output_into_a_closed_pipe_ends_quietly(tmp_path):
    """`companion eval --diff … | head`: the reader leaves early; no traceback."""
    row = {"renderer": "scene", "split": None, "seed": 0, "camera": "640×480",
           "mirrored": False, "has_obstacle": True, "detectable": True, "eta_true_deg": 30.0,
           "kind": "box"}
    old, new = tmp_path / "old.jsonl", tmp_path / "new.jsonl"
    old.write_text("".join(json.dumps({**row, "index": i, "eta_est_deg": None}) + "\n"
                           for i in range(5000)))
    new.write_text("".join(json.dumps({**row, "index": i, "eta_est_deg": 31.0}) + "\n"
                           for i in range(5000)))
    p = subprocess.Popen([*EXE, "eval", "--diff", str(old), str(new)], cwd=ROOT,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert p.stdout.read(20)  # 5000 lines are more than a pipe holds: it blocks, then breaks
    p.stdout.close()
    err = p.stderr.read().decode()
    assert p.wait(timeout=60) == 141
    assert "Traceback" not in err and "Exception ignored" not in err, err


def test_bench_prints_ratios_and_writes_the_json_keys(tmp_path):
    out = tmp_path / "bench.json"
    r = run("bench", "--frames", "2", "--repeat", "1", "--resolutions", "320x240", "640x480",
            "--no-sitl", "--json", out, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "total/detector" in r.stdout and "peak RSS" in r.stdout
    figures = json.loads(out.read_text())["resolutions"]
    assert set(figures) == {"320x240", "640x480"}
    for f in figures.values():
        for key in ("total_ms_median", "total_ms_p99", "detector_ms_median", "lsd_ms_median"):
            assert f[key] > 0
        assert f["frames"] == 2
        assert f["total_ms_p99"] >= f["total_ms_median"]


def test_bench_and_sim_reject_bad_arguments_in_one_line():
    _assert_one_line_error(run("bench", "--resolutions", "640by480", "--no-sitl"), "WxH")
    _assert_one_line_error(run("bench", "--latency-frames", "0"), "--latency-frames")
    _assert_one_line_error(run("sim", "--eta0", "120"), "between -89 and 89")
    _assert_one_line_error(run("sim", "--scenario", "approach", "--lens", "-0.5"),
                           "--lens must be between -0.2 and 0.1")
    _assert_one_line_error(run("sim", "--scenario", "approach", "--renderer", "pathtraced",
                               "--lens", "-0.05"), "draws its own lens")
    _assert_one_line_error(run("sim", "--renderer", "pathtraced"), "goes with --scenario approach")
    _assert_one_line_error(run("sim", "--eye-level"), "--eye-level goes with --scenario approach")
    _assert_one_line_error(run("sim", "--manhattan"), "--manhattan goes with --scenario approach")
    _assert_one_line_error(run("eval", "--variants"), "--variants needs --yud")
    _assert_one_line_error(run("eval", "--lens-given"), "go with --renderer")
    _assert_one_line_error(run("eval", "--renderer", "scene", "--long"), "--long goes with --clips")
    _assert_one_line_error(run("eval", "--renderer", "scene", "--clips", "--lens-given"),
                           "are for the splits")
    _assert_one_line_error(run("eval", "--mirrored"), "--mirrored goes with --renderer")
    _assert_one_line_error(run("eval", "--eye-level"), "--eye-level goes with --renderer")
    _assert_one_line_error(run("eval", "--renderer", "scene", "--clips", "--eye-level"),
                           "--eye-level goes with --renderer")
    _assert_one_line_error(run("eval", "--pitch", "10"), "--pitch goes with --renderer")
    _assert_one_line_error(run("eval", "--rug"), "--rug goes with --renderer")
    _assert_one_line_error(run("eval", "--renderer", "scene", "--clips", "--rug"),
                           "--rug goes with --renderer")
    _assert_one_line_error(run("eval", "--renderer", "scene", "--pitch", "40"),
                           "give -30 to 30 degrees")
    for extra in ((), ("--renderer", "scene", "--clips"), ("--renderer", "scene", "--lens-given")):
        _assert_one_line_error(run("eval", "--as-video", *extra), "--as-video goes with --renderer")


def test_dry_run_needs_no_mavlink_packages(sample_video):
    # The `mavlink` extra is optional: without pymavlink and mavsdk the dry-run still works.
    code = ("import sys; sys.modules['pymavlink'] = sys.modules['mavsdk'] = None; "
            "from companion.cli import main; "
            f"sys.exit(main(['--video', {str(sample_video[0])!r}, '--dry-run', '--no-progress']))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert "frames:" in r.stdout


def test_version_is_the_installed_package_version():
    from importlib.metadata import version

    proc = run("--version")
    assert proc.returncode == 0
    assert proc.stdout.strip() == f"companion {version('companion')}"


def test_a_progress_line_tells_the_time_taken_and_the_time_left_at_the_rate_so_far():
    from companion.cli import progress_line

    assert progress_line(0, 720, 0.2, "pathtraced dev") == (
        "[..............................] 0/720 pathtraced dev")
    # 180 of 720 frames in 5 minutes: 15 minutes to go at that rate.
    line = progress_line(180, 720, 300.0, "pathtraced dev")
    assert line.startswith("[#######.......................] 180/720 pathtraced dev")
    assert line.endswith("  5:00, ~15:00 left")
    assert progress_line(1, 3, 2000.0).endswith("  33:20, ~1:06:40 left")
    assert progress_line(720, 720, 61.0).endswith("720/720  1:01")  # done: nothing left
    assert progress_line(42, 0, 3.0, "frames") == "42 frames  0:03"  # a total unknown

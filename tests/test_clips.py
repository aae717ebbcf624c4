"""Scoring of the tracking clips (sitl.evaluate): per frame, tracked, and late frames."""

from sitl.evaluate import LATE_FRAME, LONG_CLIP_FRAMES, FrameResult, clip_figures, format_clips


def _clip(early_eta, late_eta, truth=20.0):
    """One long clip with a detectable obstacle: η ``early_eta`` before LATE_FRAME,
    ``late_eta`` from it on (tracked the same)."""
    rows = []
    for k in range(LONG_CLIP_FRAMES):
        eta = early_eta if k < LATE_FRAME else late_eta
        rows.append(FrameResult(0, k, True, True, truth, eta, eta))
    return rows


def test_late_rows_score_only_the_frames_after_the_lens_is_learnt():
    frames = _clip(early_eta=None, late_eta=21.0)
    lines = format_clips({"dev": frames}, "pathtraced", long=True)
    late = [line for line in lines if "late, per frame" in line]
    every = [line for line in lines if line.startswith("dev   per frame")]
    assert len(late) == 1 and len(every) == 1
    # All detections are late: 100 % there, half of the clip's frames over all of it.
    assert late[0].split()[4] == "100.0" and every[0].split()[3] == "50.0"
    f = clip_figures([r for r in frames if r.frame >= LATE_FRAME], tracked=False)
    assert f["eta_err_median_deg"] == 1.0
    assert "late" not in "\n".join(format_clips({"dev": frames}, "pathtraced"))


def test_a_mirrored_clip_is_the_reflected_room_yawing_the_other_way():
    from sitl.evaluate import evaluate_clip

    # Clip 2 of seed 0: a box 9–13° off, found in every frame.
    plain = evaluate_clip(0, 2, frames=4)
    flipped = evaluate_clip(0, 2, frames=4, mirrored=True)
    assert [r.frame for r in flipped] == [0, 1, 2, 3] and all(r.mirrored for r in flipped)
    truths = [(r.eta_true_deg, m.eta_true_deg) for r, m in zip(plain, flipped, strict=True)]
    assert all(t is not None for t, _ in truths) and len({round(t, 3) for t, _ in truths}) > 1
    assert all(m == -t for t, m in truths)
    # The pipeline finds the box both ways, with η of opposite signs.
    found = [(r.eta_deg, m.eta_deg) for r, m in zip(plain, flipped, strict=True)
             if r.eta_deg is not None and m.eta_deg is not None]
    assert found and all(a * b < 0 for a, b in found)

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

"""`radar-odom run` on the shared real city drive, against its aligned GNSS/INS reference.

The drive is ``../shared/data/real/radiate-2019-02-12-edinburgh`` (RADIATE, frames 201–480,
280 sweeps, ≈ 445 m, three intervals of ≈ 0.5 s that are late stamps, not missing sweeps: `io.timebase`):
read in place, never copied into the repository. The whole drive is run ONCE per module (through the CLI, with the
shipped default model; ≈ 15–30 s on two cores); the other real tests build small tmp copies of a
stretch of it (a hole cut into it, the sweeps mirrored) and run those.

What is pinned here and nowhere else: the run reads the unpadded-nanosecond time files, crosses
every gap, aligns the GNSS/INS reference by itself (clock ≈ +1.7 s, INS heading ≈ −7.1°), scores
a KITTI error that a broken reference or mirrored azimuths cannot reach, and RADIATE azimuths
turn the way the INS heading says.
"""
from __future__ import annotations

import io
import math
import re
import shutil
from contextlib import redirect_stderr, redirect_stdout
from types import SimpleNamespace

import numpy as np
import pytest

from radar_odom.commands.cli import main
from radar_odom.evaluation.report import evaluate
from radar_odom.evaluation.trajectory import read_kitti, read_tum
from radar_odom.odometry.gaps import GAP
from radar_odom.runs.run_sequence import read_estimates_csv
from radar_odom.se2 import chain_relative, relative_from_absolute

DRIVE_NAME = "radiate-2019-02-12-edinburgh"
SWEEPS = 280
# the recording's three ≈ 0.5 s intervals (sweeps 135, 203, 245) are late stamps, put back by the reader's
# time base (`io.timebase`, a StampWarning): no gap is left to cross. 39 stamps are late by more than the
# host's jitter band (±13.5 ms); the retired `io.stamps` repair counted 44 (its runs' tails down to 5 ms)
LATE_STAMPS = 39
# the offsets measured on the drive (its README; `gnss_ins` docstring): +1.644 s and −7.50° by the run itself
CLOCK_OFFSET_S = 1.7
HEADING_OFFSET_DEG = -7.1
# KITTI translation error of the shipped default model (cart-0.4) over the whole drive: measured 3.15 %
# (rotation 0.0215 deg/m) with the late stamps put back; 3.38 % / 0.0231 against the recorded stamps, 3.63 % /
# 0.0254 before the features' high-pass, 4.46 % / 0.0319 the release before the cubic polar rotation. A broken
# reference scores far above: INS heading left uncorrected 12.7 %, its offset applied the wrong way 25 %, clock
# offset left at 0 13.3 % (0.086 deg/m); mirrored estimates 52 %.
MAX_TRANSLATION_PERCENT = 4.0
MAX_ROTATION_DEG_PER_M = 0.03
HELD_OUT = 80  # the last sweeps, never trained or calibrated on (`radar-odom train --real-holdout`)


@pytest.fixture(scope="module")
def drive(real_data_dir):
    path = real_data_dir / DRIVE_NAME
    if not (path / "Navtech_Polar").is_dir() or not (path / "GPS_IMU_Twist").is_dir():
        pytest.skip(f"no RADIATE city drive with GNSS/INS samples at {path}")
    return path


def _stretch(drive, dst, frames, *, mirror: bool = False):
    """A RADIATE folder at ``dst`` holding only ``frames`` of ``drive`` (copied PNGs, their lines of
    the time file) and the drive's GNSS/INS reference (linked); ``mirror`` reverses the azimuth
    columns (column a ← column −a mod 400: azimuth θ read as −θ)."""
    import cv2

    polar = dst / "Navtech_Polar"
    polar.mkdir(parents=True)
    for frame in frames:
        src = drive / "Navtech_Polar" / f"{frame:06d}.png"
        if mirror:
            img = cv2.imread(str(src), cv2.IMREAD_UNCHANGED)
            assert cv2.imwrite(str(polar / src.name), img[:, (-np.arange(img.shape[1])) % img.shape[1]])
        else:
            shutil.copyfile(src, polar / src.name)
    lines = {int(ln.split()[1]): ln for ln in (drive / "Navtech_Polar.txt").read_text().splitlines() if ln.strip()}
    (dst / "Navtech_Polar.txt").write_text("".join(lines[f] + "\n" for f in frames))
    (dst / "GPS_IMU_Twist").symlink_to(drive / "GPS_IMU_Twist", target_is_directory=True)
    shutil.copyfile(drive / "GPS_IMU_Twist.txt", dst / "GPS_IMU_Twist.txt")
    return dst


def _yaw_steps(poses: np.ndarray) -> np.ndarray:
    return relative_from_absolute(poses)[:, 2]


# ---------------------------------------------------------------- the whole drive, once


@pytest.fixture(scope="module")
def drive_run(drive, tmp_path_factory):
    """``radar-odom run DRIVE -o OUT`` (defaults: shipped model, auto offsets, plot): its exit status,
    stdout, and the `RunResult` that `run_sequence` handed to the CLI (recorded on the way)."""
    import radar_odom.runs.run_sequence as run_module

    out = tmp_path_factory.mktemp("real-drive") / "out"
    results = []
    real_run_sequence = run_module.run_sequence

    def recording(*args, **kwargs):
        results.append(real_run_sequence(*args, **kwargs))
        return results[-1]

    stdout, stderr = io.StringIO(), io.StringIO()
    with pytest.MonkeyPatch.context() as mp, redirect_stdout(stdout), redirect_stderr(stderr):
        mp.setattr(run_module, "run_sequence", recording)  # the CLI imports it at call time
        status = main(["run", str(drive), "-o", str(out)])
    assert len(results) == 1
    return SimpleNamespace(status=status, printed=stdout.getvalue(), stderr=stderr.getvalue(), out=out,
                           result=results[0])


@pytest.mark.real
@pytest.mark.slow
def test_default_model_covariance_is_honest_on_the_held_out_stretch(drive_run):
    """The shipped default model's reported covariance against the aligned reference on the last
    80 sweeps (never calibrated or trained on): d² close to χ²(3) (median 2.37, 5 % above 7.81).
    Measured with this release's calibration (sim + the drive's first 200 sweeps): median 2.58,
    10 % above; with the simulation-only calibration of the release before: median 18.2, 67 %."""
    from radar_odom.evaluation.metrics import covariance_jitter, mahalanobis_sq

    r = drive_run.result
    gt_rel, est_rel = relative_from_absolute(r.gt_poses), relative_from_absolute(r.poses)
    held = np.arange(len(r.estimates)) >= SWEEPS - HELD_OUT
    good = held & np.array([not e.degenerate and GAP not in e.flags for e in r.estimates])
    covs = np.stack([e.covariance for e in r.estimates])[good]
    from radar_odom import pretrained
    from radar_odom.model_zoo import default_model_name
    from radar_odom.onnx_model import OnnxModel  # the default model's cells, for the jitter

    prof = OnnxModel(pretrained(default_model_name()), threads=1).info.profile
    jitter = covariance_jitter(prof.resolution_m, prof.rotation_step_rad)
    d2 = mahalanobis_sq(gt_rel[good] - est_rel[good], covs, jitter)
    assert good.sum() >= 70
    assert 1.0 < np.median(d2) < 5.0, np.median(d2)
    assert np.mean(d2 > 7.815) < 0.2, np.mean(d2 > 7.815)


@pytest.mark.real
@pytest.mark.slow
def test_real_drive_runs_to_the_end_with_its_late_stamps_put_back_against_the_aligned_reference(drive_run):
    run, r = drive_run, drive_run.result
    assert run.status == 0, run.stderr
    # to the end: every sweep read (time file with unpadded nanoseconds), none skipped or degenerate
    assert len(r.poses) == len(r.timestamps_us) == SWEEPS and len(r.estimates) == SWEEPS - 1
    assert r.complete and r.num_degenerate == 0 and np.all(np.diff(r.timestamps_us) > 0)
    # the late stamps put back on the sensor's period, said on stderr: no interval is a gap any more
    assert f"{LATE_STAMPS} sweep stamps were late (up to 264 ms, in 3 runs" in run.stderr, run.stderr
    # one late-stamp count per run (issue 50: a run printed 138 and 142, the reader's and the match's)
    assert set(re.findall(r"(\d+) sweep stamps were late", run.printed + run.stderr)) == {str(LATE_STAMPS)}
    dts = np.diff(r.timestamps_us) / 1e6
    gaps = [i for i, e in enumerate(r.estimates) if GAP in e.flags]
    assert gaps == [] and 0.249 < dts.min() and dts.max() < 0.251  # every interval one period, jitter gone
    assert not any(e.degenerate for e in r.estimates)
    # the reference aligned by the run itself (measured: +1.641 s; the INS heading's offset followed in
    # time, median −7.21°, from −8.51° to −4.59° over this stretch)
    ref = r.reference
    assert ref["clock_offset_found"] == "estimated" and ref["heading_offset_found"] == "followed"
    assert ref["clock_offset_s"] == pytest.approx(CLOCK_OFFSET_S, abs=0.1)
    assert ref["heading_offset_deg"] == pytest.approx(HEADING_OFFSET_DEG, abs=1.0)
    lo, hi = ref["heading_offset_range_deg"]
    assert -9.5 < lo < -7.5 and -6.0 < hi < -3.5, (lo, hi)
    assert ref["clock_second_best_ratio"] > 2.0  # measured 3.3: the alignment is not ambiguous
    # KITTI on segment lengths that fit a 445 m drive
    m = r.metrics
    assert m is not None and m["lengths_m"] == [50, 100, 150, 200, 250, 300, 350, 400]
    assert m["translation_percent"] < MAX_TRANSLATION_PERCENT, m["translation_percent"]
    assert m["rotation_deg_per_m"] < MAX_ROTATION_DEG_PER_M, m["rotation_deg_per_m"]
    assert r.gt_poses is not None and np.isfinite(r.gt_poses).all()
    path_m = np.hypot(*np.diff(r.gt_poses[:, :2, 2], axis=0).T).sum()
    assert path_m == pytest.approx(445, abs=10)
    # the files: the reference beside the estimate (the same sweeps, the same stamps), and the plot
    for name in ("trajectory.tum", "trajectory.kitti", "estimates.csv", "ground_truth.tum", "ground_truth.kitti",
                 "trajectory.png"):
        assert (run.out / name).stat().st_size > 0, name
    gt_ts, gt_tum = read_tum(run.out / "ground_truth.tum")
    assert np.array_equal(gt_ts, r.timestamps_us)
    np.testing.assert_allclose(gt_tum, r.gt_poses, atol=1e-5)
    np.testing.assert_allclose(read_kitti(run.out / "ground_truth.kitti"), r.gt_poses, atol=1e-5)
    assert (run.out / "trajectory.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    _, _, _, flags = read_estimates_csv(run.out / "estimates.csv")
    assert [i for i, f in enumerate(flags) if GAP in f] == gaps
    # what the CLI says about it
    printed = run.printed
    assert f"{SWEEPS} sweeps, {SWEEPS - 1} estimates (0 degenerate;" in printed
    assert f"reference: GNSS/INS, clock offset {ref['clock_offset_s']:+.3f} s (estimated" in printed
    assert (f"INS heading turned onto the GNSS track, its offset followed in time (±5 s running median of moving "
            f"samples): median {ref['heading_offset_deg']:+.2f} deg") in printed
    assert f"next-best minimum {ref['clock_second_best_ratio']:.2f}× that" in printed
    kitti = re.search(r"KITTI odometry \(segments of 50–400 m, step 4, .*\): translation ([0-9.]+) %, "
                      r"rotation ([0-9.]+) deg/m", printed)
    assert kitti, printed
    assert float(kitti[1]) == pytest.approx(m["translation_percent"], abs=1e-3)
    assert float(kitti[2]) == pytest.approx(m["rotation_deg_per_m"], abs=1e-5)
    assert not [ln for ln in printed.splitlines() if ln.startswith("crossed ")]
    for kind in ("gt_tum", "gt_kitti", "plot"):
        assert f"{kind}: {run.out}" in printed, kind


@pytest.mark.real
@pytest.mark.slow
def test_real_drive_azimuths_turn_the_way_the_ins_heading_turns(drive_run):
    """RADIATE sweeps carry no encoder: which way the azimuth columns turn is pinned here against
    the GNSS/INS heading. Read the other way, every turn of the estimate would be mirrored."""
    r = drive_run.result
    assert r.gt_poses is not None and np.isfinite(r.gt_poses).all()
    est_yaw, ref_yaw = _yaw_steps(r.poses), _yaw_steps(r.gt_poses)
    corr = np.corrcoef(est_yaw, ref_yaw)[0, 1]
    assert corr > 0.8, corr  # measured 0.91
    # the drive turns right overall (Oxford yaw, clockwise positive): reference +1.31 rad, estimate +1.46 rad
    assert ref_yaw.sum() > 0.5 and est_yaw.sum() > 0.5
    assert abs(est_yaw.sum() - ref_yaw.sum()) < 0.35
    # the same estimates mirrored (y → −y, yaw → −yaw, what reversed azimuths give) fail both checks
    mirrored = relative_from_absolute(r.poses) * np.array([1.0, -1.0, -1.0])
    assert np.corrcoef(mirrored[:, 2], ref_yaw)[0, 1] < -0.8
    metrics, _ = evaluate(r.gt_poses, chain_relative(mirrored))
    assert metrics["translation_percent"] > 2 * MAX_TRANSLATION_PERCENT  # measured 52 %


# ---------------------------------------------------------------- stretches of the drive (tmp copies)


@pytest.mark.real
@pytest.mark.slow
def test_real_mirrored_sweeps_turn_the_estimate_against_the_reference(drive, tmp_path):
    """The reader itself, not a mirrored pose: the same 40 sweeps (frames 341–380, a 35° left turn)
    with their azimuth columns reversed turn the estimate the other way."""
    from radar_odom.model_zoo import default_model_name, resolve_model
    from radar_odom.runs.run_sequence import run_sequence

    seq = _stretch(drive, tmp_path / "mirrored", range(341, 381), mirror=True)
    r = run_sequence(seq, resolve_model(default_model_name()), tmp_path / "out", show_progress=False, plot=False,
                     gt_time_offset=CLOCK_OFFSET_S, gt_heading_offset_deg=HEADING_OFFSET_DEG)
    est_yaw, ref_yaw = _yaw_steps(r.poses), _yaw_steps(r.gt_poses)
    # measured: correlation −0.92; reference −0.62 rad in all, estimate +0.53 rad; KITTI 40 %
    assert ref_yaw.sum() < -0.4 and est_yaw.sum() > 0.3
    assert np.corrcoef(est_yaw, ref_yaw)[0, 1] < -0.8
    assert r.metrics["translation_percent"] > 2 * MAX_TRANSLATION_PERCENT


@pytest.mark.real
@pytest.mark.slow
def test_real_hole_in_a_turn_is_crossed_and_bridged_by_the_right_distance(drive, tmp_path, capsys):
    """Frames 341–400 (≈ 150 m, a left then a right turn) with frames 384–385 deleted, in a right
    turn: the run crosses the 0.75 s hole, flags it, prints it, and its estimate over the hole
    covers the reference's distance and turn (measured: 7.22 m and 6.3° against 7.46 m and 6.4°)."""
    frames = [f for f in range(341, 401) if f not in (384, 385)]
    seq = _stretch(drive, tmp_path / "holed", frames)
    out = tmp_path / "out"
    status = main(["run", str(seq), "-o", str(out), "--no-plot",
                   "--gt-time-offset", str(CLOCK_OFFSET_S), "--gt-heading-offset-deg", str(HEADING_OFFSET_DEG)])
    printed = capsys.readouterr().out
    assert status == 0
    hole = frames.index(386) - 1  # the estimate of frame 386 in frame 383
    assert f"{len(frames)} sweeps, {len(frames) - 1} estimates (0 degenerate;" in printed
    assert "clock offset +1.700 s (given" in printed and "INS heading -7.10 deg" in printed and "(given;" in printed
    crossed = re.search(rf"crossed 1 gap\(s\) .*: sweep {hole + 1} \(([0-9.]+) s\)$", printed, re.MULTILINE)
    assert crossed, printed
    assert float(crossed[1]) == pytest.approx(0.75, abs=0.03)
    assert "KITTI odometry (segments of" in printed  # ≈ 150 m: segments of 10–80 m
    _, rel, _, flags = read_estimates_csv(out / "estimates.csv")
    assert [i for i, f in enumerate(flags) if f & {GAP}] == [hole]
    assert not any("degenerate" in f for f in flags)
    _, gt = read_tum(out / "ground_truth.tum")
    assert len(gt) == len(frames) and np.isfinite(gt).all()
    ref = relative_from_absolute(gt)[hole]
    ref_m, est_m = math.hypot(ref[0], ref[1]), math.hypot(rel[hole, 0], rel[hole, 1])
    assert ref_m > 6.0  # the car drives ≈ 10 m/s there: three sweep periods are metres, not a creep
    assert est_m == pytest.approx(ref_m, rel=0.3), (est_m, ref_m)
    assert abs(math.degrees(rel[hole, 2] - ref[2])) < 2.0, (rel[hole], ref)


# ---------------------------------------------------------------- the reference with given offsets


@pytest.mark.real
def test_real_reference_takes_given_offsets_as_given(drive):
    from radar_odom.errors import StampWarning
    from radar_odom.evaluation.reference import gnss_reference
    from radar_odom.io import read_sequence
    from radar_odom.io.gnss_ins import estimate_heading_offset_rad, poses_at
    from radar_odom.io.timebase import fit_time_base

    seq = read_sequence(drive, repair_stamps=False)  # as recorded: the reference puts the late stamps back itself
    track, ts = seq.reference, seq.timestamps_us
    unused = np.full((len(ts), 3, 3), np.nan)  # the estimate only serves to find the clock: not needed here
    followed, info_auto, _ = gnss_reference(track, ts, unused, CLOCK_OFFSET_S, None)
    assert info_auto["heading_offset_found"] == "followed" and info_auto["clock_offset_found"] == "given"
    assert info_auto["heading_offset_deg"] == pytest.approx(HEADING_OFFSET_DEG, abs=1.0)  # median −7.21°
    # one constant, as `--gt-heading-offset-deg` gives it: the offset measured on straight stretches
    measured = math.degrees(estimate_heading_offset_rad(track)[0])
    auto_heading = gnss_reference(track, ts, unused, CLOCK_OFFSET_S, measured)[0]
    # the followed offset stays within a few degrees of the constant: the same path to within metres
    assert np.nanmax(np.abs(followed[:, :2, 2] - auto_heading[:, :2, 2])) < 0.1 * 445

    poses, info, note = gnss_reference(track, ts, unused, CLOCK_OFFSET_S, measured)
    assert info["clock_offset_found"] == "given" and info["heading_offset_found"] == "given"
    assert info["clock_offset_s"] == CLOCK_OFFSET_S and info["heading_offset_deg"] == measured
    assert "clock offset +1.700 s (given;" in note and f"INS heading {measured:+.2f} deg" in note
    assert "(given; negative = clockwise)" in note
    np.testing.assert_allclose(poses, auto_heading, atol=1e-9)  # the same offsets, the same poses
    # the offsets are used as given: the track where they put it, at the sweep times with the drive's three
    # late-stamp runs put back on the sensor's period (`io.timebase`) ...
    assert info["late_stamps"] == LATE_STAMPS
    assert f"{LATE_STAMPS} sweep stamps were late (up to 264 ms, in 3 runs" in note
    assert info["early_stamps"] == 0 and info["sweeps_dropped"] == 0
    repaired = fit_time_base(ts).times_us
    np.testing.assert_allclose(poses, poses_at(track, repaired, CLOCK_OFFSET_S, math.radians(measured), 1.0),
                               atol=1e-9)
    # ... the very times the reader gives the sweeps (one time base per run: the reader's, passed on)
    with pytest.warns(StampWarning):
        fitted = read_sequence(drive)
    assert np.array_equal(fitted.timestamps_us, repaired)
    same, same_info, _ = gnss_reference(track, fitted.timestamps_us, unused, CLOCK_OFFSET_S, measured,
                                        time_base=fitted.time_base)
    np.testing.assert_array_equal(same, poses)
    assert same_info["late_stamps"] == LATE_STAMPS
    raw, raw_info, raw_note = gnss_reference(track, ts, unused, CLOCK_OFFSET_S, measured, repair_stamps=False)
    np.testing.assert_allclose(raw, poses_at(track, ts, CLOCK_OFFSET_S, math.radians(measured), 1.0), atol=1e-9)
    assert "late_stamps" not in raw_info and "were late" not in raw_note
    # where a run of late stamps was, the raw stamps' reference steps are 8 % short (sweeps 203–213)
    short = np.linalg.norm(relative_from_absolute(raw)[203:213, :2], axis=1)
    right = np.linalg.norm(relative_from_absolute(poses)[203:213, :2], axis=1)
    assert 0.88 < short.sum() / right.sum() < 0.96
    later, _, _ = gnss_reference(track, ts, unused, CLOCK_OFFSET_S + 1.0, measured)
    assert np.nanmax(np.abs(later[:, :2, 2] - poses[:, :2, 2])) > 5.0  # a second later the car is elsewhere
    # ... and another heading offset turns the whole path about the start: the same yaws, the positions
    # rotated by minus the change (a larger offset turns the heading further clockwise, so the path,
    # seen from it, counter-clockwise in the z-up world, clockwise in the Oxford frame's y-right view)
    delta = 5.0
    turned, _, _ = gnss_reference(track, ts, unused, CLOCK_OFFSET_S, measured + delta)
    np.testing.assert_allclose(_yaw_steps(turned), _yaw_steps(poses), atol=1e-9)
    far = np.hypot(poses[:, 0, 2], poses[:, 1, 2]) > 5.0
    angle = np.arctan2(turned[far, 1, 2], turned[far, 0, 2]) - np.arctan2(poses[far, 1, 2], poses[far, 0, 2])
    np.testing.assert_allclose(np.degrees(np.angle(np.exp(1j * angle))), -delta, atol=1e-6)
    np.testing.assert_allclose(np.hypot(turned[:, 0, 2], turned[:, 1, 2]), np.hypot(poses[:, 0, 2], poses[:, 1, 2]),
                               atol=1e-9)


# ---------------------------------------------------------------- the CLI's flags (no data needed)


@pytest.mark.parametrize("flag, value, says", [
    ("--gt-time-offset", "abc", "--gt-time-offset takes 'auto' or a number, got 'abc'"),
    ("--gt-heading-offset-deg", "7deg", "--gt-heading-offset-deg takes 'auto' or a number, got '7deg'"),
    ("--gt-time-offset", "nan", "--gt-time-offset must be finite, got 'nan'"),
    ("--gt-heading-offset-deg", "-inf", "--gt-heading-offset-deg must be finite, got '-inf'"),
])
def test_run_refuses_a_bad_offset_in_one_line(tmp_path, capsys, flag, value, says):
    out = tmp_path / "out"
    assert main(["run", str(tmp_path), "-o", str(out), f"{flag}={value}"]) == 1
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and says in lines[0] and lines[0].startswith("radar-odom run: error:"), captured.err
    assert not out.exists()  # refused before anything ran or was written


def test_run_help_names_the_offsets_deskew_and_gap_crossing(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["run", "--help"])
    assert exit_info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps lines
    for flag in ("--gt-time-offset auto|SECONDS", "--gt-heading-offset-deg auto|DEGREES", "--deskew, --no-deskew",
                 "--max-gap-s"):
        assert flag in text, flag
    assert "Gaps in the recording are crossed and reported" in text
    assert "every gap is crossed, its estimate flagged 'gap'" in text
    assert "RADIATE GNSS/INS aligned in time and heading" in text

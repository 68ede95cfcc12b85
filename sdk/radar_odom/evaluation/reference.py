"""A reference trajectory for a recording: RADIATE's GNSS/INS track at the radar's times, its
clock aligned to the radar's and its heading turned onto the direction of travel."""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError, SequenceError

# the automatic clock alignment is refused below these: a next-best minimum this close in cost
# (1.17–1.42 on short, straight or non-overlapping windows that aligned 4–15 s wrong; 1.92 on the
# shared drive, right), or this few radar pairs compared inside the track
MIN_CLOCK_SECOND_BEST_RATIO = 1.5
MIN_CLOCK_PAIRS = 40


def gnss_reference(track, timestamps_us, est_poses, time_offset_s=None, heading_offset_deg=None,
                   repair_stamps: bool = True, time_base=None):
    """(reference poses float64[N, 3, 3] at ``timestamps_us``, info dict, one-line note) from a
    GNSS/INS track, its clock and heading offsets given or found from the data.

    The sweep times: ``time_base`` (a `radar_odom.io.timebase.TimeBase`, e.g. ``Sequence.time_base``:
    the very times the reader gave the sweeps, one answer per run) where given, ``timestamps_us``
    then being its fitted times or its recorded stamps; else, with ``repair_stamps``, the time base
    fitted here on ``timestamps_us`` (RADIATE's host stamps run up to 0.27 s late for a dozen sweeps
    at a time, which made the reference's steps 8 % short there and one step double); else the
    stamps as given. ``info["late_stamps"]`` / ``["early_stamps"]`` count the stamps moved.

    The clock (None): by aligning ``est_poses``' yaw increments and step lengths with the track's
    (`gnss_ins.estimate_clock_offset_s`); refused with a `SequenceError` (the reference is then not
    used) where the alignment is ambiguous (next-best minimum under `MIN_CLOCK_SECOND_BEST_RATIO`
    × the best's cost) or compares under `MIN_CLOCK_PAIRS` pairs: a wrong clock is worse than none.
    The heading (None): the INS heading turned onto the GNSS track direction, the offset followed
    in time (`gnss_ins.heading_offset_track_rad`: the INS re-aligns while driving); a number (°):
    that one offset for the whole drive.
    """
    import math

    from ..io import gnss_ins
    from ..io.timebase import fit_time_base
    from ..se2 import relative_from_absolute

    info = {}
    base = time_base
    if base is not None:
        check_time_base(base, timestamps_us)
    elif repair_stamps and len(timestamps_us):
        base = fit_time_base(timestamps_us)
    if base is not None:
        timestamps_us = base.times_us
        corr = base.corrections_us
        info.update(late_stamps=int(base.late.size), early_stamps=int(base.early.size),
                    late_stamps_max_s=float(max(corr.max(), 0)) / 1e6, sweeps_dropped=base.dropped,
                    sensor_period_s=base.period_s)
    if heading_offset_deg is None:
        offsets = gnss_ins.heading_offset_track_rad(track)
        deg = np.degrees(offsets)
        t = track.seconds_since_start()
        # where it steps: the largest change of the followed offset over 10 s
        later = np.interp(t + 10.0, t, deg)
        k = int(np.argmax(np.abs(later - deg)))
        info.update(heading_offset_deg=float(np.median(deg)), heading_offset_found="followed",
                    heading_offset_range_deg=(float(deg.min()), float(deg.max())),
                    heading_offset_step_deg=float(later[k] - deg[k]), heading_offset_step_at_s=float(t[k]))
        heading = offsets
    else:
        info.update(heading_offset_deg=float(heading_offset_deg), heading_offset_found="given")
        heading = math.radians(float(heading_offset_deg))
    if time_offset_s is None:
        clock = gnss_ins.estimate_clock_offset_s(track, timestamps_us, relative_from_absolute(est_poses))
        info.update(clock_offset_s=float(clock.offset_s), clock_offset_found="estimated", clock_cost=float(clock.cost),
                    clock_pairs=int(clock.num_pairs), clock_second_best_ratio=float(clock.second_best_ratio))
        if clock.num_pairs < MIN_CLOCK_PAIRS or clock.second_best_ratio < MIN_CLOCK_SECOND_BEST_RATIO:
            raise SequenceError(
                f"the radar and GNSS/INS clocks cannot be aligned with confidence: best offset {clock.offset_s:+.3f} s "
                f"over {clock.num_pairs} pairs (need {MIN_CLOCK_PAIRS}), the next-best minimum costs only "
                f"{clock.second_best_ratio:.2f}× as much (need {MIN_CLOCK_SECOND_BEST_RATIO}); the radar and the "
                "track overlap too little or drive too straight — give the offset with --gt-time-offset S"
            )
    else:
        info.update(clock_offset_s=float(time_offset_s), clock_offset_found="given")
    # the track has holes of up to 0.8 s (shared drive): interpolating a car across them errs by centimetres
    poses = gnss_ins.poses_at(track, timestamps_us, info["clock_offset_s"], heading, max_sample_gap_s=1.0)
    check_overlap(track, timestamps_us, poses, info["clock_offset_s"], info["clock_offset_found"])
    if info["clock_offset_found"] == "estimated":
        clock_how = (f"estimated from the odometry's yaw rate and speed over {info['clock_pairs']} pairs, cost "
                     f"{info['clock_cost']:.3g}, next-best minimum {info['clock_second_best_ratio']:.2f}× that")
    else:
        clock_how = "given"
    if info["heading_offset_found"] == "followed":
        lo, hi = info["heading_offset_range_deg"]
        head = (f"INS heading turned onto the GNSS track, its offset followed in time (±5 s running median of moving "
                f"samples): median {info['heading_offset_deg']:+.2f} deg, range {lo:+.2f} … {hi:+.2f} deg, largest "
                f"change {info['heading_offset_step_deg']:+.2f} deg within 10 s from "
                f"{info['heading_offset_step_at_s']:.0f} s into the track; negative = clockwise")
    else:
        head = (f"INS heading {info['heading_offset_deg']:+.2f} deg from the direction of travel (given; "
                "negative = clockwise), turned onto it")
    note = (f"reference: GNSS/INS, clock offset {info['clock_offset_s']:+.3f} s ({clock_how}; the reference for "
            f"radar time t is the sample at t + offset), {head}")
    if base is not None and base.summary():
        note += f"; {base.summary()} before sampling the track"
    return poses, info, note


def check_time_base(base, timestamps_us) -> None:
    """`ConfigError` where ``timestamps_us`` are neither the time base's fitted times nor its stamps:
    a time base of another recording (or another stretch) would time the reference wrongly."""
    t = np.asarray(timestamps_us, dtype=np.int64).reshape(-1)
    if not (t.shape == base.times_us.shape and (np.array_equal(t, base.times_us) or np.array_equal(t, base.stamps_us))):
        raise ConfigError(f"time_base does not belong to these {t.size} sweep times: it holds {base.times_us.size} "
                          "sweeps whose times and stamps both differ from them; pass the Sequence.time_base of the "
                          "recording the times come from, or none")


def check_overlap(track, timestamps_us, poses, offset_s: float, found: str) -> None:
    """`SequenceError` where the clock offset leaves fewer than two radar times on the track: an offset
    of 1e12 s gave an all-NaN reference that passed as "9 of 9 steps lack ground truth" and an empty
    ground_truth.tum. The caller then leaves the reference unused and says why."""
    n = len(timestamps_us)
    known = int(np.isfinite(np.asarray(poses).reshape(n, -1)).all(axis=1).sum()) if n else 0
    if known >= 2 or n < 2:
        return
    t = np.asarray(timestamps_us, dtype=np.int64)
    shift_us = offset_s * 1e6
    track_s = (track.times_us[-1] - track.times_us[0]) / 1e6
    start_s = (t[0] + shift_us - track.times_us[0]) / 1e6  # where the radar's first time falls on the track
    raise SequenceError(
        f"the clock offset {offset_s:+.6g} s ({found}) puts {n - known} of the {n} radar times outside the GNSS/INS "
        f"track or in its gaps: the radar's first time falls {start_s:+.6g} s from the track's start, which spans "
        f"{track_s:.1f} s; give an offset that puts the drive on the track (--gt-time-offset S; the reference for "
        "radar time t is the sample at t + offset), or 'auto' to estimate it"
    )

"""Within-sweep azimuth slips of a real recording: while the car stands still, does every row of a
sweep line up with the same row of the previous sweep?

    python benchmarks/azimuth_slips.py [--drive ../shared/data/real/radiate-2019-02-12-edinburgh]

For every consecutive pair whose GNSS/INS reference moves less than ``--still-m`` (aligned as
``radar-odom run`` aligns it) and turns less than 0.05°, each azimuth row ``a`` of the later
sweep is compared with rows ``a + s`` (s = −3 … 3 bins) of the earlier one over 5–60 m of
range (a 9-row band, normalised cross-correlation of log power), and the best shift is kept. A
static scene seen by a sensor whose azimuths are where its reader says gives s = 0 on every row;
a rotation of the car gives one constant s; a shift that *changes within the sweep* (0 up to some
row, ±1 after it) is a slip of the azimuth encoding. Prints one line per still pair: the share
of rows at each shift, the first row of 20 consecutive rows off 0, and the yaw the default model
reads for that pair (the reference's is ≈ 0). Reads the recording where it lies.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

DRIVE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real" / "radiate-2019-02-12-edinburgh"
SHIFTS = np.arange(-3, 4)
RUN = 20  # rows in a row off 0 that count as a slip


def row_shifts(prev: np.ndarray, cur: np.ndarray, band: int = 9) -> np.ndarray:
    """int[A]: per azimuth row of ``cur`` [A, R], the shift s (bins) for which rows a + s of
    ``prev`` match best (normalised cross-correlation over a ``band``-row window, circular)."""
    def norm(x):
        x = np.log1p(x * 255.0)
        x = x - x.mean(axis=1, keepdims=True)
        return x / (np.linalg.norm(x, axis=1, keepdims=True) + 1e-9)

    p, c = norm(prev), norm(cur)
    k = np.ones(band) / band
    scores = []
    for s in SHIFTS:
        per_row = np.sum(c * np.roll(p, -s, axis=0), axis=1)  # row a of cur against row a + s of prev
        padded = np.concatenate([per_row[-band:], per_row, per_row[:band]])
        scores.append(np.convolve(padded, k, mode="same")[band:-band])
    return SHIFTS[np.argmax(np.stack(scores), axis=0)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drive", type=Path, default=DRIVE,
                    help="a RADIATE recording with GPS_IMU_Twist/ (default: the shared drive)")
    ap.add_argument("--still-m", type=float, default=0.05,
                    help="largest reference step of a still pair (default: %(default)s m)")
    args = ap.parse_args(argv)
    if not (args.drive / "GPS_IMU_Twist").is_dir():
        print(f"{args.drive}: no RADIATE recording with GPS_IMU_Twist/ there (the shared real data?)", file=sys.stderr)
        return 2
    from radar_odom import RadarOdometer, pretrained
    from radar_odom.evaluation.reference import gnss_reference
    from radar_odom.io import read_sequence
    from radar_odom.se2 import relative_from_absolute

    seq = read_sequence(args.drive)
    scans = [f.scan for f in seq]
    odo = RadarOdometer(pretrained("cart-0.4"), motion_prior=False)
    ests = [odo.step(s) for s in scans][1:]
    gt, _, note = gnss_reference(seq.reference, seq.timestamps_us, odo.trajectory.poses)
    print(note)
    ref = relative_from_absolute(gt)  # float[N-1, 3]: x m, y m, yaw rad
    lr = (5.0 / scans[0].range_resolution_m, 60.0 / scans[0].range_resolution_m)
    cols = slice(int(lr[0]), int(lr[1]))
    print("\n| pair | reference step m | shares of rows at shift -1 / 0 / +1 bins | first of 20 rows off 0 "
          "| model yaw ° |")
    print("|---|---:|---|---:|---:|")
    slipped, still, yaws = 0, 0, []
    for k in range(len(ref)):
        if not (np.hypot(*ref[k, :2]) < args.still_m and abs(np.degrees(ref[k, 2])) < 0.05):
            continue
        still += 1
        s = row_shifts(scans[k].power[:, cols], scans[k + 1].power[:, cols])
        off = s != 0
        # the first row of a run of RUN rows all off 0 (single rows flip on noise)
        runs = np.convolve(off.astype(int), np.ones(RUN, int), mode="valid") == RUN
        first = int(np.argmax(runs)) if runs.any() else None
        slipped += bool(off.mean() > 0.25)
        shares = " / ".join(f"{np.mean(s == v):.2f}" for v in (-1, 0, 1))
        yaw = np.degrees(ests[k].pose[2])
        yaws.append(yaw)
        first_txt = "—" if first is None else str(first)
        print(f"| {k}→{k + 1} | {np.hypot(*ref[k, :2]):.3f} | {shares} | {first_txt} | {yaw:+.2f} |")
    if still:
        print(f"\n{still} still pairs; {slipped} with more than a quarter of their rows shifted; model yaw RMS "
              f"{np.sqrt(np.mean(np.square(yaws))):.2f}° (reference ≈ 0)")
    else:
        print("no still pair in this recording")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

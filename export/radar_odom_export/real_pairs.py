"""Real recordings as training pairs: their reference poses, a held-out stretch, skip-k pairs, and
the mix with simulated pairs in every batch.

* `real_drive` reads a recording with any supported ground truth (Oxford
  ``gt/radar_odometry.csv``, Boreas / MulRan poses, a RADIATE GNSS/INS track aligned in clock and
  heading as ``radar-odom run`` aligns it: `radar_odom.evaluation.reference.gnss_reference`, the clock from the
  shipped default model's odometry of the same sweeps) onto a profile's grid, and cuts its last
  ``holdout`` sweeps off: that stretch is never a training pair, so it stays an honest test.
* `SkipPairs` indexes every pair (k, k + s), s = 1 … ``max_skip``, of real drives, its pose the
  composition of the s relative poses, keeping those inside the search window: skipping sweeps
  shows the masker the larger motions of a fast car or a dropped sweep.
* `MixedPairs` is the training set: item i is a simulated pair, or with probability
  ``real_fraction`` (drawn from (seed, epoch, i), so a resumed run sees the same) a real one;
  with batch 8 and 0.25, 90 % of batches hold at least one real pair and the mean is 2.
* `GainFloor` randomises a real pair's gain and noise floor, as each simulated drive draws its
  own radar: the graph normalises both away, so the masker must not learn one radar's levels.

Real sweeps are non-commercial data: they are read where they lie and cached only under the
user's cache folder (`radar_odom_export.data.cache_dir`), never in the repository.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from radar_odom._progress import progress
from radar_odom.errors import SequenceError
from radar_odom.profiles import GridProfile
from radar_odom.se2 import relative_from_absolute, se2_batch, to_xyyaw

from .data import (
    CACHE_VERSION,
    NO_AUGMENT,
    Augment,
    Drive,
    PairDataset,
    _stable_hash,
    cache_dir,
    grid_key,
    pose_runs,
    scan_to_cartesian,
)

DEFAULT_HOLDOUT = 80  # sweeps at the end of each real recording that training never sees (105 m of the shared drive)
DEFAULT_MAX_SKIP = 4


def reference_relative(seq) -> tuple[np.ndarray, dict]:
    """(float64[N−1, 3] Oxford relative poses, info) of a recording's ground truth.

    Its own (Oxford / Boreas / MulRan: ``seq.gt_relative``), or its GNSS/INS track aligned:
    heading offset measured on the track, clock offset estimated from the shipped default
    model's odometry of the same sweeps (info holds both, as ``radar-odom run`` prints them).
    Raises `SequenceError` when the recording has neither.
    """
    if seq.gt_relative is not None:
        return np.asarray(seq.gt_relative, dtype=np.float64), {"reference": "recording's own ground truth"}
    track = getattr(seq, "reference", None)
    if track is None:
        raise SequenceError(
            f"{seq.root}: no ground truth (Oxford gt/radar_odometry.csv, Boreas/MulRan poses, or a RADIATE "
            "GPS_IMU_Twist/ folder); a real recording for training needs one"
        )
    from radar_odom import RadarOdometer, pretrained
    from radar_odom.evaluation.reference import gnss_reference
    from radar_odom.model_zoo import default_model_name

    odo = RadarOdometer(pretrained(default_model_name()))
    for frame in progress(seq, desc=f"aligning the reference of {seq.root.name}", unit="sweep"):
        odo.step(frame.scan)
    gt, info, _ = gnss_reference(track, seq.timestamps_us, odo.trajectory.poses)
    info["reference"] = "GNSS/INS"
    return relative_from_absolute(gt), info


def _cache_path(profile: GridProfile, seq) -> Path:
    stamp = [str(Path(seq.root).resolve()), len(seq), int(seq.timestamps_us[0]), int(seq.timestamps_us[-1])]
    return cache_dir() / "real" / f"v{CACHE_VERSION}_{grid_key(profile)}_{_stable_hash(stamp)}.npz"


def real_drive(path, profile: GridProfile, holdout: int = DEFAULT_HOLDOUT, use_cache: bool = True) -> Drive:
    """The recording at ``path`` on ``profile``'s grid with its reference poses, its last
    ``holdout`` sweeps cut off (`reference_relative`; pairs without a reference are NaN rows,
    which `SkipPairs` leaves out). Cached per (recording, grid) under the cache folder."""
    from radar_odom.io import read_sequence

    seq = read_sequence(path)
    if len(seq) - int(holdout) < 2:
        raise SequenceError(
            f"{path}: {len(seq)} sweeps, {holdout} held out: fewer than two left to train on "
            "(give a longer recording or a smaller --real-holdout)"
        )
    cache = _cache_path(profile, seq)
    if use_cache and cache.exists():
        with np.load(cache) as z:
            images, poses = z["images"], z["poses_rel"]
    else:
        rel, _ = reference_relative(seq)
        images = np.stack([scan_to_cartesian(f.scan, profile).astype(np.float16)
                           for f in progress(seq, desc=f"reading {Path(path).name}", unit="sweep")])
        poses = rel.astype(np.float32)
        if use_cache:
            cache.parent.mkdir(parents=True, exist_ok=True)
            tmp = cache.with_name(f".{cache.name}.{os.getpid()}.tmp")
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, images=images, poses_rel=poses)
            os.replace(tmp, cache)
    keep = len(images) - int(holdout)
    return Drive(f"{Path(path).name}[:{keep}]", images[:keep], poses[: keep - 1])


def real_runs(path, profile: GridProfile, holdout: int = DEFAULT_HOLDOUT, use_cache: bool = True) -> list[Drive]:
    """`real_drive` cut into runs of consecutive sweeps whose every pair has a reference (a pair
    without one, e.g. across a hole in the GNSS/INS track, ends a run), each named
    ``real:<recording>-<first sweep>``: drives for calibration and evaluation, where every
    consecutive pair is used as it is (`calibrate.pair_weights` finds them by that prefix)."""
    d = real_drive(path, profile, holdout, use_cache)
    runs = [Drive(f"real:{Path(path).name}-{a}", d.images[a : b + 1], d.poses_rel[a:b])
            for a, b in pose_runs(d.poses_rel)]
    if not runs:
        raise SequenceError(f"{path}: no consecutive pair with a reference pose outside the held-out stretch")
    return runs


def window_limits(profile: GridProfile) -> tuple[float, float]:
    """(largest |x|, |y| in m, largest |yaw| in rad) of a pose the profile's search can read,
    one cell / one yaw step inside the window's edge."""
    max_t = (profile.translation_cells - 1) * profile.resolution_m
    return max_t, profile.rotation_range_rad - profile.rotation_step_rad


class SkipPairs:
    """Pairs (k, k + s) of drives, s = 1 … ``max_skip``, whose composed pose fits the window.

    Item i -> dict like `radar_odom_export.data.PairDataset`'s (``prev``, ``cur``, ``pose``),
    after ``augment`` and ``gain_floor`` (drawn from (seed, epoch, i)).
    """

    def __init__(self, drives, profile: GridProfile, max_skip: int = DEFAULT_MAX_SKIP, augment: Augment = NO_AUGMENT,
                 gain_floor: GainFloor | None = None, seed: int = 0):
        self.drives = list(drives)
        self.augment, self.gain_floor, self.seed, self.epoch = augment, gain_floor, int(seed), 0
        max_t, max_yaw = window_limits(profile)
        index, poses = [], []
        for d_idx, d in enumerate(self.drives):
            rel = np.asarray(d.poses_rel, dtype=np.float64)
            for k in range(len(rel)):
                pose = np.eye(3)
                for s in range(1, int(max_skip) + 1):
                    if k + s > len(rel) or not np.all(np.isfinite(rel[k + s - 1])):
                        break
                    pose = pose @ se2_batch(rel[k + s - 1][None])[0]
                    xyyaw = to_xyyaw(pose)
                    if max(abs(xyyaw[0]), abs(xyyaw[1])) > max_t or abs(xyyaw[2]) > max_yaw:
                        break  # a longer skip only moves further
                    index.append((d_idx, k, k + s))
                    poses.append(xyyaw)
        self.index = index
        self.poses = np.asarray(poses, dtype=np.float32).reshape(-1, 3)

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, i: int) -> dict:
        d_idx, a, b = self.index[i]
        d = self.drives[d_idx]
        prev, cur = d.images[a].astype(np.float32), d.images[b].astype(np.float32)
        rng = np.random.default_rng((self.seed, self.epoch, i, 1))
        if self.gain_floor is not None:
            prev, cur = self.gain_floor(rng, prev), self.gain_floor(rng, cur)
        prev, cur, pose, _ = self.augment(rng, prev, cur, self.poses[i].copy())
        return {"prev": np.ascontiguousarray(prev), "cur": np.ascontiguousarray(cur), "pose": pose}


@dataclass(frozen=True)
class GainFloor:
    """Per sweep: power × gain (log-uniform in ``gain``) + a floor (uniform in ``floor``), clipped
    to [0, 1]; zero stays zero where the image is empty (the blanked near range, outside the disc)."""

    gain: tuple[float, float] = (0.5, 2.0)
    floor: tuple[float, float] = (0.0, 0.05)

    def __call__(self, rng: np.random.Generator, img: np.ndarray) -> np.ndarray:
        g = math.exp(rng.uniform(math.log(self.gain[0]), math.log(self.gain[1])))
        f = rng.uniform(*self.floor)
        return np.where(img > 0, np.clip(img * g + f, 0.0, 1.0), 0.0).astype(np.float32)


class MixedPairs:
    """Simulated pairs with real ones mixed in: item i is real with probability ``real_fraction``
    (a real pair drawn uniformly), else simulated pair i; both drawn from (seed, epoch, i)."""

    def __init__(self, sim: PairDataset, real: SkipPairs, real_fraction: float, seed: int = 0):
        if not 0.0 < real_fraction < 1.0:
            raise ValueError(f"real_fraction must be in (0, 1), got {real_fraction!r}")
        if len(real) == 0:
            raise SequenceError("no real training pair fits the search window; check the real recordings")
        self.sim, self.real, self.real_fraction, self.seed, self.epoch = sim, real, float(real_fraction), int(seed), 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)
        self.sim.set_epoch(epoch)
        self.real.set_epoch(epoch)

    def __len__(self) -> int:
        return len(self.sim)

    def __getitem__(self, i: int) -> dict:
        rng = np.random.default_rng((self.seed, self.epoch, i, 2))
        if rng.random() < self.real_fraction:
            return self.real[int(rng.integers(len(self.real)))]
        return self.sim[i]

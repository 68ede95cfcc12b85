"""Training pairs: Cartesian sweeps with their ground-truth relative poses, cached on disk.

A *drive* is one continuous recording converted to the Cartesian grid of a profile:
``images`` float16[F, W, W] (one per sweep, near range blanked), optionally ``labels``
float16[F, W, W] (the simulator's static-world label, resampled onto the same grid, for the
supervised-mask baseline) and ``poses_rel`` float32[F-1, 3]: row k is the Oxford relative pose
(x m, y m, yaw rad) of sweep k+1 in sweep k's frame. Pairs never cross drives, so the
validation split is by drive.

Seed policy for simulated drives (keeps test, training, validation and evaluation worlds
disjoint; a seed names a procedural world, so sharing one would leak it):

==================  ===========  ==========================================
use                 seeds        where
==================  ===========  ==========================================
tests               0 - 99       ``tests/``
training            1000 - 1999  ``radar-odom train --sim-seeds``
validation          2000 - 2999  model selection in training, and calibration
held-out evaluation 5000 +       ``benchmarks/eval_models.py``
==================  ===========  ==========================================

Cache: one compressed ``.npz`` (float16 images) per (profile name + grid, scenario, seed,
frames, simulator-config hash) under ``$RADAR_ODOM_CACHE`` (default ``~/.cache/radar-odom``),
never inside the repository. Writes are atomic (temp file + rename) so concurrent ranks or
runs never read half a file.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from radar_odom._progress import progress
from radar_odom.errors import RadarOdomError, SequenceError
from radar_odom.profiles import GridProfile
from radar_odom.sim import SIMULATOR_VERSION

TEST_SEEDS = range(0, 100)
TRAIN_SEEDS = range(1000, 2000)
VAL_SEEDS = range(2000, 3000)
EVAL_SEED_START = 5000
SCENARIOS = ("urban", "heavy_traffic", "open", "highway")

# bump when the cached arrays change meaning (conversion, label definition, ...)
CACHE_VERSION = 1




class DataSpecError(RadarOdomError, ValueError):
    """A data request is unusable: bad seed list, seeds outside their policy range, bad profile."""


# ----------------------------------------------------------------------------- drives
@dataclass
class Drive:
    """One recording on a profile's Cartesian grid (see the module docstring for shapes)."""

    name: str
    images: np.ndarray  # float16[F, W, W]
    poses_rel: np.ndarray  # float32[F-1, 3], sweep k+1 in sweep k's frame (Oxford)
    labels: np.ndarray | None = None  # float16[F, W, W] in [0, 1], or None

    @property
    def num_pairs(self) -> int:
        return int(len(self.poses_rel))

    def path_length_m(self) -> float:
        return float(np.linalg.norm(self.poses_rel[:, :2], axis=1).sum())


@dataclass(frozen=True)
class DriveSpec:
    """A simulated drive: which world (scenario, seed), how long, with which simulator config."""

    scenario: str
    seed: int
    frames: int
    config: object | None = None  # a simulator config (dataclass) or None for the defaults

    @property
    def name(self) -> str:
        return f"{self.scenario}-{self.seed}"


def sim_specs(seeds: Iterable[int], scenarios: Sequence[str], frames: int, config=None) -> list[DriveSpec]:
    """Every (scenario, seed) combination, scenario-major, as drive specs."""
    return [DriveSpec(sc, int(s), int(frames), config) for sc in scenarios for s in seeds]


SENSORS = ("randomised", "oxford", "radiate")


def sensor_specs(
    seeds: Iterable[int], scenarios: Sequence[str], frames: int, sensor: str = "randomised"
) -> list[DriveSpec]:
    """Like `sim_specs`, with the radar chosen by ``sensor``: a preset of `radar_odom.sim.presets`
    for every drive, or ``"randomised"``: one `randomised_config` draw per (scenario, seed), so a
    model trained on them sees many gains, noise floors, speckle and clutter levels."""
    from radar_odom.sim import SCENARIOS as PRESETS_BY_NAME
    from radar_odom.sim import get_sensor_preset, randomised_config

    if sensor not in SENSORS:
        raise DataSpecError(f"sensor {sensor!r}: choose one of {', '.join(SENSORS)}")
    names = list(PRESETS_BY_NAME)
    specs = []
    for sc in scenarios:
        for s in seeds:
            if sensor == "randomised":
                cfg = randomised_config(int(s) * 16 + (names.index(sc) if sc in names else 15))
            else:
                cfg = None if sensor == "oxford" else get_sensor_preset(sensor)
            specs.append(DriveSpec(sc, int(s), int(frames), cfg))
    return specs


def parse_seeds(text: str) -> list[int]:
    """``"1000-1003,1010"`` -> [1000, 1001, 1002, 1003, 1010] (ranges inclusive)."""
    out: list[int] = []
    for part in str(text).replace(" ", "").split(","):
        if not part:
            continue
        lo, _, hi = part.partition("-")
        if not lo.isdigit() or (hi and not hi.isdigit()):
            raise DataSpecError(f"seed {part!r}: write non-negative integers or ranges low-high, comma-separated")
        lo_i, hi_i = int(lo), int(hi or lo)
        if hi_i < lo_i:
            raise DataSpecError(f"seed range {part!r} is empty (write low-high)")
        out.extend(range(lo_i, hi_i + 1))
    return out


def check_seed_policy(seeds: Iterable[int], use: str) -> None:
    """Raise `DataSpecError` when ``seeds`` leave the range reserved for ``use`` (see module doc)."""
    allowed = {"train": TRAIN_SEEDS, "val": VAL_SEEDS, "test": TEST_SEEDS}
    seeds = list(seeds)
    if use == "eval":
        bad = [s for s in seeds if s < EVAL_SEED_START]
        rng = f">= {EVAL_SEED_START}"
    else:
        r = allowed[use]
        bad = [s for s in seeds if s not in r]
        rng = f"{r.start}-{r.stop - 1}"
    if bad:
        raise DataSpecError(f"{use} seeds must be {rng} (seed policy in radar_odom_export.data); got {bad[:5]}")


# ----------------------------------------------------------------------------- cache
def cache_dir() -> Path:
    """``$RADAR_ODOM_CACHE`` or ``~/.cache/radar-odom`` (created on demand)."""
    return Path(os.environ.get("RADAR_ODOM_CACHE") or Path.home() / ".cache" / "radar-odom")


def _stable_hash(obj) -> str:
    if obj is None:
        return "default"
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        obj = dataclasses.asdict(obj)
    text = json.dumps(obj, sort_keys=True, default=repr)
    return hashlib.sha1(text.encode()).hexdigest()[:10]


def grid_key(profile: GridProfile) -> str:
    """Cache key of what the Cartesian conversion depends on (name alone may be reused)."""
    geo = (profile.resolution_m, profile.width_px, profile.near_range_m)
    return f"{profile.name}-{_stable_hash(geo)}"


def drive_cache_path(profile: GridProfile, spec: DriveSpec, root: Path | None = None) -> Path:
    root = cache_dir() if root is None else Path(root)
    name = (
        f"v{CACHE_VERSION}-sim{SIMULATOR_VERSION}_{grid_key(profile)}_{spec.scenario}_s{spec.seed}"
        f"_f{spec.frames}_{_stable_hash(spec.config)}.npz"
    )
    return root / "drives" / name


def save_drive(path: Path, drive: Drive) -> None:
    """Compressed float16 npz, written atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {"images": drive.images.astype(np.float16), "poses_rel": drive.poses_rel.astype(np.float32)}
    if drive.labels is not None:
        arrays["labels"] = drive.labels.astype(np.float16)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    os.replace(tmp, path)


def load_drive(path: Path, name: str, with_labels: bool = True) -> Drive:
    with np.load(path) as z:
        labels = z["labels"] if with_labels and "labels" in z.files else None
        return Drive(name=name, images=z["images"], poses_rel=z["poses_rel"], labels=labels)


# ----------------------------------------------------------------------------- conversion
def scan_to_cartesian(scan, profile: GridProfile) -> np.ndarray:
    """float32[W, W] Cartesian image of a sweep on the profile's grid, near range blanked."""
    from radar_odom.polar import polar_to_cartesian

    return polar_to_cartesian(scan, profile.resolution_m, profile.width_px, near_range_m=profile.near_range_m)


def label_to_cartesian(label_polar: np.ndarray, scan, profile: GridProfile) -> np.ndarray:
    """float32[W, W] in [0, 1]: a polar static-world label [A, B] resampled like the sweep.

    Any nonzero label value counts as static (labels may be 0/1 or 0/255); bilinear
    resampling then gives the fraction of static power around each Cartesian cell.
    """
    from radar_odom.polar import polar_to_cartesian_array

    lab = (np.asarray(label_polar) > 0).astype(np.float32)
    return polar_to_cartesian_array(
        lab,
        scan.azimuths_rad,
        scan.range_resolution_m,
        scan.range_offset_m,
        profile.resolution_m,
        profile.width_px,
        near_range_m=profile.near_range_m,
    )


def simulate_drive_arrays(profile: GridProfile, spec: DriveSpec, seconds: float | None = None) -> Drive:
    """Simulate ``spec`` and convert every sweep and label to the profile's grid (no cache).

    ``seconds``: stop after the sweep at which that long has passed (at least `MIN_CUT_FRAMES` sweeps): a drive
    cut short, whose world was still built for all ``spec.frames`` (`build_drives` with ``cut``)."""
    from radar_odom.sim import simulate_drive

    until = None if seconds is None else time.perf_counter() + seconds
    images, labels, poses = [], [], []
    for k, frame in enumerate(simulate_drive(spec.seed, spec.frames, scenario=spec.scenario, config=spec.config)):
        images.append(scan_to_cartesian(frame.scan, profile).astype(np.float16))
        labels.append(label_to_cartesian(frame.static_label, frame.scan, profile).astype(np.float16))
        if k > 0:
            poses.append(np.asarray(frame.pose_rel, dtype=np.float64).reshape(3))
        if until is not None and k + 1 >= MIN_CUT_FRAMES and time.perf_counter() > until:
            break
    return Drive(
        name=spec.name,
        images=np.stack(images),
        labels=np.stack(labels),
        poses_rel=np.asarray(poses, dtype=np.float32).reshape(-1, 3),
    )


MIN_CUT_FRAMES = 12  # a drive cut short by a budget keeps at least this many sweeps


def _build_one(job) -> tuple[int, float, int, Drive | None]:
    """Pool worker: simulate, convert and cache one drive; returns (index, seconds, sweeps, None). A drive cut
    short (``job``'s end, a `time.time` value the parent set: it counts a spawned worker's start too;
    `simulate_drive_arrays`) is returned in place of None and not cached: its world was built for the whole drive,
    so it is not the shorter drive its sweep count would name in the cache."""
    idx, profile, spec, root, until = job
    cv2.setNumThreads(1)  # one process per core already
    t0 = time.perf_counter()
    drive = simulate_drive_arrays(profile, spec) if until is None else \
        simulate_drive_arrays(profile, spec, seconds=until - time.time())
    if len(drive.images) < spec.frames:
        return idx, time.perf_counter() - t0, len(drive.images), drive
    save_drive(drive_cache_path(profile, spec, root), drive)
    return idx, time.perf_counter() - t0, len(drive.images), None


def _ignore_ctrl_c() -> None:
    """Pool worker start: Ctrl-C, which a terminal sends to every process of the command, is the parent's to
    handle (it stops the pool, whose workers then end); without this each worker printed its own traceback."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def build_drives(
    profile: GridProfile,
    specs: Sequence[DriveSpec],
    workers: int = 2,
    with_labels: bool = True,
    root: Path | None = None,
    desc: str = "simulating drives",
    deadline: float | None = None,
    min_drives: int = 1,
    report: dict | None = None,
    cut: bool = False,
) -> list[Drive]:
    """Drives for ``specs`` on ``profile``'s grid: from the cache, the missing ones simulated.

    Missing drives are generated by a ``multiprocessing`` pool of ``workers`` processes
    (spawned: the parent may hold torch's thread pools, which do not survive ``fork``).

    ``deadline`` (a `time.perf_counter` value): a share of a wall-clock budget. Simulation then
    starts no drive it expects to end after it (expected: the mean time of the drives simulated so
    far), stops waiting for those in flight once it has passed, and returns the drives that are
    ready, in the order of ``specs`` — at least ``min_drives`` of them (counting cached ones), however
    long those take. Missing drives are simulated round-robin over the scenarios, so a cut keeps
    every scenario it can. Without ``deadline``, every drive of ``specs``.
    ``cut`` (with ``deadline``): rather than leave drives out, give each drive begun its share of the time left
    (the time left over the rounds of ``workers`` drives still to run) and cut it short there, at
    `MIN_CUT_FRAMES` sweeps at least (such drives are not cached); a drive still starts only while the quickest
    so far would end by the deadline, and those in flight are waited for a tenth of the share longer.
    ``report`` (a dict) receives ``asked``, ``ready``, ``cached``, ``simulated``, ``left_out``, ``cut_short``
    (drives), ``sweeps`` ([sweeps ready, sweeps asked]) and ``seconds`` (simulating).
    """
    t0 = time.perf_counter()
    paths = [drive_cache_path(profile, s, root) for s in specs]
    todo = [(i, profile, s, root) for i, (s, p) in enumerate(zip(specs, paths)) if not p.exists()]
    cached = len(specs) - len(todo)
    plan = _Plan(deadline, max(0, min_drives - cached), workers, cut and deadline is not None)
    if plan.cut:  # a drive in flight ends at the deadline by itself (its last sweep, its transfer): wait for it
        plan.grace = max(1.0, 0.1 * (deadline - t0))
    if todo:
        if deadline is not None:
            todo = _round_robin(todo)
        bar = progress(total=len(todo), desc=desc, unit="drive")
        if workers > 1 and len(todo) > 1:
            _build_in_pool(todo, plan, bar)
        else:
            _build_in_turn(todo, plan, bar)
        bar.close()
    # under a deadline, the drives whose file is whole (written atomically; a drive abandoned in flight may
    # still have reached it) and those cut short; without one, every drive (a missing file is an error, as it
    # always was)
    ready = ([k for k, p in enumerate(paths) if p.exists() or k in plan.cut_drives] if deadline is not None
             else list(range(len(specs))))
    drives = [plan.cut_drives[k] if k in plan.cut_drives else load_drive(paths[k], specs[k].name, with_labels)
              for k in ready]
    if not with_labels:
        drives = [dataclasses.replace(x, labels=None) if x.labels is not None else x for x in drives]
    if report is not None:
        report.update(asked=len(specs), ready=len(ready), cached=cached, simulated=len(ready) - cached,
                      left_out=len(specs) - len(ready), cut_short=len(plan.cut_drives),
                      sweeps=[int(sum(len(x.images) for x in drives)), int(sum(s.frames for s in specs))],
                      seconds=time.perf_counter() - t0)
    return drives


class _Plan:
    """When `build_drives` may start another drive, with how many seconds to simulate it (``cut``), and what it
    got back: the drives' times, the drives built (indices) and those cut short (index -> `Drive`)."""

    def __init__(self, deadline: float | None, owed: int, workers: int, cut: bool):
        self.deadline, self.owed, self.workers, self.cut = deadline, owed, max(1, workers), cut
        self.times: list[float] = []  # seconds each drive took
        self.shortest: list[float] = []  # the seconds of its first MIN_CUT_FRAMES sweeps, pro rata
        self.built: list[int] = []
        self.cut_drives: dict[int, Drive] = {}
        self.grace = 0.0  # how long past the deadline the drives in flight are waited for

    def may_start(self, in_flight: int = 0) -> bool:
        """No deadline; fewer drives ready or started than owed (the floor); or the next drive expected to end by
        the deadline: the mean drive so far, or where drives are cut the shortest cut (`MIN_CUT_FRAMES` sweeps at
        the quickest pace so far); none yet: any time before it."""
        if self.deadline is None or self.owed - len(self.built) - in_flight > 0:
            return True
        expect = 0.0
        if self.times:
            expect = min(self.shortest) if self.cut else sum(self.times) / len(self.times)
        return time.perf_counter() + expect <= self.deadline

    def job(self, todo_job, left: int) -> tuple:
        """``todo_job`` with when to cut it (a `time.time` value, so that a spawned worker can read it): None, or
        (``cut``) now + the time left over the rounds of the ``left`` drives still to start (this one included)."""
        until = None
        if self.cut:
            rounds = -(-left // self.workers)
            until = time.time() + max(0.0, self.deadline - time.perf_counter()) / rounds
        return (*todo_job, until)

    def took(self, result) -> None:
        idx, secs, sweeps, drive = result
        self.built.append(idx)
        self.times.append(secs)
        self.shortest.append(secs * min(1.0, MIN_CUT_FRAMES / max(sweeps, 1)))
        if drive is not None:
            self.cut_drives[idx] = drive


def _round_robin(todo: list) -> list:
    """``todo`` (jobs of `build_drives`) reordered to take each scenario in turn: the first n cover as
    many scenarios as n allows."""
    by_scenario: dict[str, list] = {}
    for job in todo:
        by_scenario.setdefault(job[2].scenario, []).append(job)
    queues = list(by_scenario.values())
    out = []
    while any(queues):
        for q in queues:
            if q:
                out.append(q.pop(0))
    return out


def _build_in_turn(todo: list, plan: _Plan, bar) -> None:
    """`build_drives` in this process: drive after drive while the plan lets one start."""
    for n, job in enumerate(todo):
        if not plan.may_start():
            break
        plan.took(_build_one(plan.job(job, len(todo) - n)))
        bar.update(1)


def _build_in_pool(todo: list, plan: _Plan, bar) -> None:
    """`build_drives` on a spawned pool: at most ``workers`` drives in flight, a new one only while the plan lets
    it; past the deadline (the floor met) the drives in flight are abandoned, their half-written temporary files
    removed."""
    import multiprocessing as mp

    queue, pending = list(todo), {}
    with mp.get_context("spawn").Pool(min(plan.workers, len(todo)), initializer=_ignore_ctrl_c) as pool:
        while queue or pending:
            while queue and len(pending) < plan.workers and plan.may_start(len(pending)):
                job = plan.job(queue.pop(0), len(queue) + 1)
                pending[job[0]] = (job, pool.apply_async(_build_one, (job,)))
            if not pending:
                break
            for idx in [i for i, (_, r) in pending.items() if r.ready()]:
                plan.took(pending.pop(idx)[1].get())  # a worker's exception is raised here
                bar.update(1)
            if plan.deadline is not None and len(plan.built) >= plan.owed and \
                    time.perf_counter() > plan.deadline + plan.grace:
                break
            time.sleep(0.05)
        # leaving the block terminates the pool: the drives still in flight are abandoned
    for job, _ in pending.values():
        path = drive_cache_path(job[1], job[2], job[3])
        for tmp in path.parent.glob(f".{path.name}.*.tmp"):
            tmp.unlink(missing_ok=True)


# ----------------------------------------------------------------------------- recordings
def _sequence_cache_path(profile: GridProfile, seq_dir: Path, root: Path | None) -> Path:
    seq_dir = Path(seq_dir).resolve()
    radar = sorted((seq_dir / "radar").glob("*.png"))
    stamp = [str(seq_dir), len(radar)]
    for f in radar[-1:] + [seq_dir / "gt" / "radar_odometry.csv"]:
        if f.exists():
            stamp.append(f.stat().st_mtime_ns)
    root = cache_dir() if root is None else Path(root)
    return root / "sequences" / f"v{CACHE_VERSION}_{grid_key(profile)}_{_stable_hash(stamp)}.npz"


def sequence_drives(seq_dir, profile: GridProfile, root: Path | None = None, use_cache: bool = True) -> list[Drive]:
    """A recorded sequence (Oxford/Boreas/MulRan folder) on the profile's grid, with gt poses.

    A training pair needs a ground-truth relative pose: where a pair has none (NaN row) the
    recording is cut there, so one folder may give several drives (``name[0]``, ``name[1]``...).
    Raises `SequenceError` when no two consecutive sweeps have ground truth.
    """
    from radar_odom.io import read_sequence

    seq_dir = Path(seq_dir)
    cache = _sequence_cache_path(profile, seq_dir, root)
    if use_cache and cache.exists():
        with np.load(cache) as z:
            images, poses = z["images"], z["poses_rel"]
    else:
        seq = read_sequence(seq_dir)
        if seq.gt_relative is None:
            raise SequenceError(
                f"{seq_dir}: no ground truth found; training needs gt/radar_odometry.csv "
                "(Boreas: applanix/radar_poses.csv, MulRan: global_pose.csv)"
            )
        if len(seq) < 2:
            raise SequenceError(f"{seq_dir}: needs at least two sweeps to make a training pair, found {len(seq)}")
        images = np.stack(
            [
                scan_to_cartesian(f.scan, profile).astype(np.float16)
                for f in progress(seq, desc=f"reading {seq_dir.name}", unit="sweep")
            ]
        )
        poses = np.asarray(seq.gt_relative, np.float64).reshape(-1, 3).astype(np.float32)
        if use_cache:
            cache.parent.mkdir(parents=True, exist_ok=True)
            tmp = cache.with_name(f".{cache.name}.{os.getpid()}.tmp")
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, images=images, poses_rel=poses)
            os.replace(tmp, cache)
    drives = pose_runs(poses)
    if not drives:
        raise SequenceError(f"{seq_dir}: no pair of consecutive sweeps has a ground-truth pose")
    if len(drives) == 1:
        a, b = drives[0]
        return [Drive(seq_dir.name, images[a : b + 1], poses[a:b])]
    return [Drive(f"{seq_dir.name}[{i}]", images[a : b + 1], poses[a:b]) for i, (a, b) in enumerate(drives)]


def pose_runs(poses_rel: np.ndarray) -> list[tuple[int, int]]:
    """[(a, b)]: the runs of sweeps a..b (inclusive) whose every consecutive pair has a pose
    (rows a..b−1 of ``poses_rel`` [F−1, 3] finite): a pair without ground truth (NaN row) ends one."""
    ok = np.all(np.isfinite(poses_rel), axis=1)
    runs, start = [], 0
    for k in range(len(ok) + 1):
        if k == len(ok) or not ok[k]:
            if k > start:  # pairs start..k-1 -> sweeps start..k
                runs.append((start, k))
            start = k + 1
    return runs


def split_by_drive(drives: Sequence[Drive], val_fraction: float = 0.2) -> tuple[list[Drive], list[Drive]]:
    """(train, val): the last ``ceil(val_fraction · n)`` drives are held out.

    With a single drive there is nothing to hold out whole, so it is cut in two contiguous
    blocks in time (first 80 % / last 20 %) and no pair spans the cut — still a split by place
    and time, never by shuffled pairs.
    """
    drives = list(drives)
    if not drives:
        raise SequenceError("no drives to split: give at least one sequence folder")
    if len(drives) == 1:
        d = drives[0]
        if d.num_pairs < 4:
            raise SequenceError(f"{d.name}: {d.num_pairs} pairs are too few to split into train and validation")
        cut = max(2, int(round(len(d.images) * (1 - val_fraction))))
        cut = min(cut, len(d.images) - 2)
        lab = d.labels
        head = Drive(d.name + "[train]", d.images[:cut], d.poses_rel[: cut - 1], None if lab is None else lab[:cut])
        tail = Drive(d.name + "[val]", d.images[cut:], d.poses_rel[cut:], None if lab is None else lab[cut:])
        return [head], [tail]
    n_val = max(1, math.ceil(val_fraction * len(drives)))
    return drives[:-n_val], drives[-n_val:]


# ----------------------------------------------------------------------------- augmentation
def mirror_pair(prev, cur, pose, labels=None):
    """Left/right mirror (y -> -y): flip image columns; pose (x, y, yaw) -> (x, -y, -yaw).

    Exact: columns map y=(c-cW)·res to -y because the grid is symmetric about cW=(W-1)/2, and
    M·R(yaw)·M = R(-yaw) for M = diag(1, -1).
    """
    x, y, yaw = pose
    out_labels = None if labels is None else tuple(lab[:, ::-1] for lab in labels)
    return prev[:, ::-1], cur[:, ::-1], np.array([x, -y, -yaw], np.float32), out_labels


def swap_pair(prev, cur, pose, labels=None):
    """Play the pair backwards: (cur, prev) with the inverse pose (-R(-yaw)·t, -yaw)."""
    x, y, yaw = (float(v) for v in pose)
    c, s = math.cos(yaw), math.sin(yaw)
    inv = np.array([-(c * x + s * y), -(-s * x + c * y), -yaw], np.float32)
    out_labels = None if labels is None else (labels[1], labels[0])
    return cur, prev, inv, out_labels


def rotation_warp_matrix(phi_rad: float, width_px: int) -> np.ndarray:
    """float64[2, 3]: ``cv2.warpAffine`` inverse map (dst pixel -> src pixel) rotating the
    image content by ``phi_rad`` about the sensor (pixel (cW, cW), cW = (W-1)/2), positive
    phi turning +x towards +y like yaw; see `rotate_pair`.

    With x = (cW - r)·res, y = (c - cW)·res the content rotation p' = R(phi)·p samples the
    source at R(-phi)·p', which in (column u, row v) pixels is the matrix below.
    """
    c, s, cw = math.cos(phi_rad), math.sin(phi_rad), (width_px - 1) / 2.0
    return np.array([[c, s, cw * (1 - c - s)], [-s, c, cw * (1 - c + s)]], dtype=np.float64)


def rotate_image(img: np.ndarray, phi_rad: float) -> np.ndarray:
    """Rotate a [W, W] Cartesian image's content by ``phi_rad`` about the sensor (bilinear, zero fill)."""
    w = img.shape[-1]
    m = rotation_warp_matrix(phi_rad, w)
    out = cv2.warpAffine(
        np.ascontiguousarray(img, dtype=np.float32),
        m,
        (w, w),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0.0,
    )
    return out


def rotate_pair(prev, cur, pose, phi_rad: float, labels=None):
    """Rotate both sweeps by the same ``phi_rad`` about the sensor: pose -> (R(phi)·t, yaw).

    Both frames turn by -phi, so a static point p (earlier frame) = R(yaw)·q + t becomes
    R(phi)·p = R(yaw)·(R(phi)·q) + R(phi)·t: the translation rotates, the yaw is unchanged.
    Corners rotated in from outside the image are zero (the sweep reaches beyond them).
    """
    x, y, yaw = (float(v) for v in pose)
    c, s = math.cos(phi_rad), math.sin(phi_rad)
    new_pose = np.array([c * x - s * y, s * x + c * y, yaw], np.float32)
    out_labels = None if labels is None else tuple(rotate_image(lab, phi_rad) for lab in labels)
    return rotate_image(prev, phi_rad), rotate_image(cur, phi_rad), new_pose, out_labels


@dataclass(frozen=True)
class Augment:
    """Label-exact augmentations, each applied independently per pair."""

    mirror_p: float = 0.5
    swap_p: float = 0.5
    rotate_max_rad: float = 0.0  # uniform in ±this; 0 disables (zero corners change statistics)

    def __call__(self, rng: np.random.Generator, prev, cur, pose, labels=None):
        if rng.random() < self.mirror_p:
            prev, cur, pose, labels = mirror_pair(prev, cur, pose, labels)
        if rng.random() < self.swap_p:
            prev, cur, pose, labels = swap_pair(prev, cur, pose, labels)
        if self.rotate_max_rad > 0:
            phi = rng.uniform(-self.rotate_max_rad, self.rotate_max_rad)
            prev, cur, pose, labels = rotate_pair(prev, cur, pose, phi, labels)
        return prev, cur, pose, labels


NO_AUGMENT = Augment(0.0, 0.0, 0.0)


# ----------------------------------------------------------------------------- torch dataset
class PairDataset:
    """Indexable pairs over drives: item i -> dict of float32 arrays.

    ``prev``/``cur`` [W, W], ``pose`` [3] (cur in prev's frame), and when the drives carry labels
    and ``with_labels``: ``label_prev``/``label_cur`` [W, W]. Augmentation draws from a
    generator seeded by (seed, epoch, index), so a resumed or distributed run sees the same
    pair variant for the same (epoch, index) on any rank.
    """

    def __init__(
        self, drives: Sequence[Drive], augment: Augment = NO_AUGMENT, with_labels: bool = False, seed: int = 0
    ):
        self.drives = list(drives)
        self.augment = augment
        self.with_labels = with_labels
        self.seed = int(seed)
        self.epoch = 0
        if with_labels and any(d.labels is None for d in self.drives):
            missing = [d.name for d in self.drives if d.labels is None]
            raise SequenceError(
                f"supervised masks need static-world labels, but {missing[:3]} have none "
                "(only simulated drives carry labels)"
            )
        counts = np.array([d.num_pairs for d in self.drives], dtype=np.int64)
        self._offsets = np.concatenate([[0], np.cumsum(counts)])

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return int(self._offsets[-1])

    def __getitem__(self, i: int) -> dict:
        if not 0 <= i < len(self):
            raise IndexError(i)
        d_idx = int(np.searchsorted(self._offsets, i, side="right") - 1)
        k = int(i - self._offsets[d_idx])
        d = self.drives[d_idx]
        prev = d.images[k].astype(np.float32)
        cur = d.images[k + 1].astype(np.float32)
        pose = d.poses_rel[k].astype(np.float32)
        labels = (d.labels[k].astype(np.float32), d.labels[k + 1].astype(np.float32)) if self.with_labels else None
        rng = np.random.default_rng((self.seed, self.epoch, i))
        prev, cur, pose, labels = self.augment(rng, prev, cur, pose, labels)
        item = {"prev": np.ascontiguousarray(prev), "cur": np.ascontiguousarray(cur), "pose": pose}
        if labels is not None:
            item["label_prev"] = np.ascontiguousarray(labels[0])
            item["label_cur"] = np.ascontiguousarray(labels[1])
        return item


# ----------------------------------------------------------------------------- toy drives
def render_points(
    points_xy_m: np.ndarray, weights: np.ndarray, resolution_m: float, width_px: int, sigma_px: float = 0.8
) -> np.ndarray:
    """float32[W, W]: Gaussian blobs at metric points [P, 2] (x fwd, y right) on the Cartesian grid.

    Separable: a point's blob is the outer product of a row profile and a column profile, so
    the image is one [W, P] @ [P, W] matmul.
    """
    cw = (width_px - 1) / 2.0
    idx = np.arange(width_px, dtype=np.float64)
    rows = cw - points_xy_m[:, 0] / resolution_m  # x = (cW − r)·res
    cols = cw + points_xy_m[:, 1] / resolution_m  # y = (c − cW)·res
    gr = np.exp(-0.5 * ((idx[None, :] - rows[:, None]) / sigma_px) ** 2)  # [P, W]
    gc = np.exp(-0.5 * ((idx[None, :] - cols[:, None]) / sigma_px) ** 2)
    return ((gr * np.asarray(weights, np.float64)[:, None]).T @ gc).astype(np.float32)


def toy_drive(
    profile: GridProfile,
    frames: int,
    seed: int,
    num_static: int = 150,
    num_followers: int = 12,
    noise: float = 0.05,
    name: str | None = None,
) -> Drive:
    """A tiny synthetic drive for tests and smoke runs (no radar simulator involved).

    Static point reflectors scattered around the path, plus *followers*: reflectors that move
    with the ego (static in the sensor frame, the paper's worst distractor), plus uniform noise.
    Raw correlation is pulled towards zero motion by the followers; a mask that drops them
    (the label marks only static reflectors) fixes it — so learning has something to learn.
    Ego steps: x ∈ [0.3, 0.7]·max_translation, |y| small, |yaw| within half the rotation range.
    """
    rng = np.random.default_rng(seed)
    extent = profile.extent_m
    m = profile.max_translation_m
    rel = np.column_stack(
        [
            rng.uniform(0.3 * m, 0.7 * m, frames - 1),
            rng.normal(0.0, 0.1 * m, frames - 1).clip(-0.3 * m, 0.3 * m),
            rng.uniform(-0.5, 0.5, frames - 1) * profile.rotation_range_rad,
        ]
    )
    from radar_odom.se2 import chain_relative, invert

    absolute = chain_relative(rel)  # world <- frame k
    span = np.abs(absolute[:, :2, 2]).max() + 1.5 * extent
    world = rng.uniform(-span, span, (num_static * max(1, int(span / extent)) ** 2, 2))
    w_static = rng.uniform(0.4, 1.0, len(world))
    followers = rng.uniform(-0.8 * extent, 0.8 * extent, (num_followers, 2))
    w_follow = rng.uniform(0.8, 1.0, num_followers)
    images, labels = [], []
    for k in range(frames):
        to_frame = invert(absolute[k])
        pts = world @ to_frame[:2, :2].T + to_frame[:2, 2]
        near = np.all(np.abs(pts) < extent + 3 * profile.resolution_m, axis=1)
        static = render_points(pts[near], w_static[near], profile.resolution_m, profile.width_px)
        moving = render_points(followers, w_follow, profile.resolution_m, profile.width_px)
        img = static + moving + noise * rng.random((profile.width_px,) * 2, dtype=np.float32)
        images.append(np.clip(img, 0, 1).astype(np.float16))
        labels.append((static > 0.25).astype(np.float16))
    return Drive(name or f"toy-{seed}", np.stack(images), rel.astype(np.float32), np.stack(labels))


# ----------------------------------------------------------------------------- from the CLI
def folder_drives(paths: Sequence, profile: GridProfile) -> list[list[Drive]]:
    """Drives of each recording folder (one list per folder, see `sequence_drives`)."""
    return [sequence_drives(p, profile) for p in paths]


def split_folders(per_folder: Sequence[Sequence[Drive]], val_fraction: float = 0.2) -> tuple[list[Drive], list[Drive]]:
    """Hold out whole folders (the last ``ceil(val_fraction·n)``); one folder: `split_by_drive`."""
    if len(per_folder) == 1:
        return split_by_drive(per_folder[0], val_fraction)
    n_val = max(1, math.ceil(val_fraction * len(per_folder)))
    train = [d for f in per_folder[:-n_val] for d in f]
    val = [d for f in per_folder[-n_val:] for d in f]
    return train, val

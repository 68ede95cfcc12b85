"""Adapt a shipped model to a user's own radar, without ground truth: `radar-odom adapt`.

The signal is the recording itself:

1. **Pseudo-labels from the runtime**: the shipped model runs over the recording as
   ``radar-odom run`` runs it (`RadarOdometer`: motion prior, gap crossing, degenerate sweeps
   bridged); its chain of relative poses is the label of every consecutive pair.
2. **The vehicle's constraint** (`vehicle_chord`, on by default): a car does not slide sideways,
   so over one sweep its radar moves along the chord of the arc it turns on: direction = half the
   yaw. Each label keeps the runtime's step length and yaw and takes that direction. On the shared
   RADIATE drive the shipped model's steps point 1.5–1.7° to the right of travel where the car
   drove straight (`benchmarks/adapt.py`); the chord removes that bias from the labels. It assumes
   a radar on a car looking along its axis (``--no-vehicle-prior`` for anything else).
3. **Composition**: pairs (k, k + s), s = 1 … ``max_skip``, are labelled with the composition of
   the s consecutive labels (`real_pairs.SkipPairs`). The shipped model reads a longer step
   shorter (on the shared drive 0.97 of the reference over one sweep, 0.90 over two, 0.83 over
   three): being told that two sweeps move as far as their two steps is a signal no reference
   is needed for.

Those pairs, gain and floor randomised, are mixed with simulated pairs (``real_fraction`` of each
batch real) so the masker does not forget the simulated radars, and the masker is fine-tuned with
the shipped training loss (`train.train`, cross-entropy). The recording's last ``holdout_fraction``
is never trained on: it is the validation (pose error against its pseudo-labels, best epoch
kept) and the report (`self_consistency` there, and KITTI where the recording has a reference).

4. **The radar's mount yaw** (`mount_yaw_from`, with the vehicle prior): the median direction of
   a model's straight steps on the training part, against the car's axis; written into the graph
   as ``radar_odom.mount_yaw_rad``, and the runtime turns every match by it (`turn_frame`).

Two candidates leave: the base's masker and the fine-tuned one, each with its own mount yaw;
`choose_masker` writes the fine-tuned one only where its held-out matches compose at least as
well as the base's (A→C against A→B ∘ B→C, translation and yaw: no reference needed) and it did
not collapse toward standing still (`check_collapse`: a mask that keeps only sensor-fixed content
reads every step shorter).

Under ``torchrun`` (``dist``: `train.init_distributed`) every rank reads the recordings and labels its
share of them (`labels_on_ranks`), trains on its shard of the pairs inside `train.train`'s
DistributedDataParallel, and only rank 0 exports, scores and writes; the others return None.
"""
from __future__ import annotations

import json
import math
import os
import shutil
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from radar_odom._progress import progress
from radar_odom.errors import ConfigError, RadarOdomError, SequenceError
from radar_odom.se2 import invert, se2_batch, to_xyyaw, turn_frame, wrap_angle

ADAPT_FORMAT = "radar-odom-adapt/1"
DEFAULT_MINUTES = 12.0  # simulated drives + training; with reading, labelling, export, report ≈ 16 min for 230 sweeps
SIM_SHARE = 0.4  # of the budget, at most, for simulating the drives not yet cached (train.SIM_TRAIN_SHARE's share)
MIN_HELD, MIN_TRAIN = 4, 8  # sweeps: a held-out stretch needs triplets to compare, training a few pairs
MIN_SWEEPS = MIN_HELD + MIN_TRAIN
COLLAPSE_RATIO = 0.85  # adapted / shipped mean step length on the held-out stretch below this: refused
MIN_CHORD_STEP_M = 0.3  # steps shorter than this keep their direction (standing still: none to impose)
MIN_STRAIGHT_STEPS = 10  # straight steps needed to measure the radar's mount yaw


def training_minutes(minutes: float, simulating_s: float) -> float:
    """What a budget of ``minutes`` (simulating + training) leaves for training after ``simulating_s`` seconds of
    simulating: the rest, but never less than its share (1 − `SIM_SHARE`): the simulation stops starting drives
    at its share, and one drive it must finish (a slow machine) is not taken out of the training."""
    return max(minutes - simulating_s / 60.0, (1.0 - SIM_SHARE) * minutes)


@dataclass
class AdaptConfig:
    """What `adapt` depends on (written into the checkpoint's ``train`` record and the report)."""

    base: str = "cart-0.4"  # a shipped model's name or a checkpoint written by `radar-odom train`
    minutes: float = DEFAULT_MINUTES
    lr: float = 2e-4
    batch: int = 8
    epochs: int = 4  # validation (and best-checkpoint choice) after each; the budget may end it sooner
    real_fraction: float = 0.7
    max_skip: int = 4
    holdout_fraction: float = 0.2
    vehicle_prior: bool = True
    sim_seeds: tuple[int, ...] = (1000, 1001)
    sim_frames: int = 40
    sim_scenarios: tuple[str, ...] = ("urban", "heavy_traffic", "open", "highway")
    threads: int | None = None
    seed: int = 0
    resume: bool = False
    keep: str = "auto"  # which masker to write: "auto" (`choose_masker`), "base" or "fine-tuned"
    info: dict = field(default_factory=dict)


def vehicle_chord(rel_xyyaw: np.ndarray, min_step_m: float = MIN_CHORD_STEP_M) -> np.ndarray:
    """float64[N, 3]: relative poses (x m, y m, yaw rad; sweep k + 1 in sweep k's frame) with each
    step's translation turned onto the chord of a no-slip arc: direction yaw / 2 (backwards:
    π + yaw / 2), length and yaw kept. Steps shorter than ``min_step_m`` and non-finite rows are
    returned unchanged (a car standing still has no direction to impose)."""
    rel = np.array(rel_xyyaw, dtype=np.float64, copy=True).reshape(-1, 3)
    length = np.hypot(rel[:, 0], rel[:, 1])
    ok = np.isfinite(rel).all(axis=1) & (length >= float(min_step_m))
    forward = np.where(rel[:, 0] >= 0.0, 1.0, -1.0)
    half = 0.5 * rel[:, 2]
    rel[ok, 0] = (forward * length * np.cos(half))[ok]
    rel[ok, 1] = (forward * length * np.sin(half))[ok]
    return rel


def straight_steps(rel_xyyaw: np.ndarray, min_step_m: float = 1.0, straight_deg: float = 0.5) -> np.ndarray:
    """bool[N]: forward steps of at least ``min_step_m`` turning less than ``straight_deg``."""
    rel = np.asarray(rel_xyyaw, dtype=np.float64).reshape(-1, 3)
    with np.errstate(invalid="ignore"):
        return np.isfinite(rel).all(axis=1) & (rel[:, 0] >= min_step_m) & (np.abs(np.degrees(rel[:, 2])) < straight_deg)


def direction_bias_deg(rel_xyyaw: np.ndarray, min_step_m: float = 1.0, straight_deg: float = 0.5) -> float:
    """Median angle (°, toward +y) between a step's translation and its chord direction (yaw / 2)
    over `straight_steps`: what a radar looking along its car's axis reads as 0. NaN without such
    steps."""
    rel = np.asarray(rel_xyyaw, dtype=np.float64).reshape(-1, 3)
    ok = straight_steps(rel, min_step_m, straight_deg)
    if not ok.any():
        return math.nan
    return float(np.degrees(np.median(np.arctan2(rel[ok, 1], rel[ok, 0]) - 0.5 * rel[ok, 2])))


def mount_yaw_from(rel_xyyaw: np.ndarray, min_steps: int = MIN_STRAIGHT_STEPS) -> float | None:
    """The radar's yaw on its car (rad) that turns the straight steps of ``rel_xyyaw`` (a model's
    relative poses, radar frame) onto the car's axis: minus their `direction_bias_deg`; None with
    fewer than ``min_steps`` straight steps (a drive that never goes straight says nothing)."""
    if int(straight_steps(rel_xyyaw).sum()) < int(min_steps):
        return None
    return -math.radians(direction_bias_deg(rel_xyyaw))


def set_mount_yaw(path, mount_yaw_rad: float) -> None:
    """Write ``radar_odom.mount_yaw_rad`` into the model file at ``path`` (in place, atomically),
    checked by reading it back as the runtime does."""
    import onnx

    from radar_odom.model_file import ModelInfo

    path = Path(path)
    proto = onnx.load(str(path))
    kept = [p for p in proto.metadata_props if p.key != "radar_odom.mount_yaw_rad"]
    del proto.metadata_props[:]
    proto.metadata_props.extend(kept)
    entry = proto.metadata_props.add()
    entry.key, entry.value = "radar_odom.mount_yaw_rad", repr(float(mount_yaw_rad))
    ModelInfo.from_metadata({p.key: p.value for p in proto.metadata_props}, source=str(path))
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    onnx.save(proto, str(tmp))
    os.replace(tmp, path)


@dataclass
class Recording:
    """One recording, read: its usable sweeps, their times, and the pseudo-labels of `label`."""

    name: str
    scans: list
    timestamps_us: np.ndarray
    sequence: object = None  # what `open_recording` gave (for its ground truth / GNSS/INS track)
    skipped: int = 0
    first: int = 0  # index in the recording of its first sweep used (``--sweeps``)
    poses: np.ndarray | None = None  # float64[N, 3, 3]: the base model's run (pseudo-labels, reference clock)


def parse_sweeps(text: str | None) -> slice:
    """``"A:B"`` (Python slice of a recording's sweeps; either side may be empty) → slice."""
    if text is None:
        return slice(None)
    a, sep, b = str(text).partition(":")
    try:
        if not sep:
            raise ValueError
        return slice(int(a) if a.strip() else None, int(b) if b.strip() else None)
    except ValueError:
        raise ConfigError(f"--sweeps {text!r}: give A:B (sweep indices, either may be empty, e.g. :200)") from None


def read_recording(source, topic: str | None = None, sweeps: slice = slice(None)) -> Recording:
    """The readable sweeps ``sweeps`` of a recording folder or bag (`radar_odom.io.recording.open_recording`);
    unreadable ones are counted and left out (a gap the runtime crosses)."""
    from radar_odom.io.recording import open_recording

    seq = open_recording(source, topic)
    scans, skipped = [], 0
    indices = range(len(seq))[sweeps]
    for i in progress(indices, desc=f"reading {Path(source).name}", unit="sweep"):
        try:
            scans.append(seq.scan(i))
        except RadarOdomError:
            skipped += 1
    if len(scans) < MIN_SWEEPS:
        raise SequenceError(f"{source}: {len(scans)} readable sweeps; adapting needs at least {MIN_SWEEPS} "
                            f"(a few minutes of driving are better: ~230 sweeps take ~15 min)")
    stamps = np.array([s.timestamp_us for s in scans], dtype=np.int64)
    return Recording(Path(source).name, scans, stamps, seq, skipped, indices.start if len(indices) else 0)


def run_runtime(model_path, scans, threads: int | None = None, desc: str = "odometry") -> tuple[np.ndarray, np.ndarray]:
    """``radar-odom run``'s defaults (`RadarOdometer`) over ``scans``: (absolute poses float64[N, 3, 3],
    relative poses float64[N − 1, 3] between consecutive sweeps, NaN rows where it had no
    measurement: a degenerate sweep bridged by the prior)."""
    from radar_odom import RadarOdometer

    odo = RadarOdometer(model_path, threads=threads)
    rel = np.full((max(len(scans) - 1, 0), 3), np.nan)
    for k, scan in enumerate(progress(scans, desc=desc, unit="sweep")):
        est = odo.step(scan)  # every step after the first: the sweep in the previous one's frame
        if est is not None and not est.degenerate:
            rel[k - 1] = est.pose
    return np.asarray(odo.trajectory.poses, dtype=np.float64), rel


def has_reference(seq) -> bool:
    """Whether a recording carries ground truth or a GNSS/INS track (`reference_kitti` can score)."""
    return getattr(seq, "gt_relative", None) is not None or getattr(seq, "reference", None) is not None


def stream_matcher(model_path, scans, threads: int | None = None):
    """``match(a, b) -> float64[3]``: the stream graph's own pose of sweep ``b`` in sweep ``a``'s
    frame (no motion prior), in the vehicle's frame where the model carries a mount yaw, as the
    runtime gives it. Every sweep's graph input and state are made once, up front."""
    from radar_odom.odometry.sweep_input import graph_input
    from radar_odom.onnx_model import OnnxModel

    m = OnnxModel(model_path, threads=threads)
    info = m.info
    if info.form != "stream":
        raise ConfigError(f"{model_path}: pairs are matched with a stream-form model, not {info.form}")
    x_name, s_name = info.inputs
    zero = np.zeros(info.state_shape, dtype=np.float32)
    xs = [graph_input(s, info) for s in scans]
    states = [m.run({x_name: x, s_name: zero})["state"] for x in xs]

    def match(a: int, b: int) -> np.ndarray:
        pose = np.asarray(m.run({x_name: xs[b], s_name: states[a]})["pose"], dtype=np.float64).reshape(3)
        return turn_frame(pose, None, info.mount_yaw_rad)[0] if info.mount_yaw_rad else pose

    return match


def self_consistency(model_path, scans, threads: int | None = None) -> dict:
    """How well a model's own matches agree, on ``scans`` (no reference needed).

    With the stream graph alone (`stream_matcher`): A→C against A→B ∘ B→C over every triplet of
    consecutive sweeps. Returns ``composition_t_m`` / ``composition_yaw_deg`` (RMS of the
    difference, m / °), ``skip2_scale`` (|A→C| / |A→B ∘ B→C|, mean over moving triplets: 1 for
    a matcher whose step does not depend on how far it is), ``mean_step_m`` (mean length of the
    consecutive matches) and ``direction_deg` (`direction_bias_deg` of them).
    """
    match = stream_matcher(model_path, scans, threads)
    n = len(scans)
    one = np.array([match(k, k + 1) for k in range(n - 1)])
    two = np.array([match(k, k + 2) for k in range(n - 2)])
    composed = to_xyyaw(se2_batch(one[:-1]) @ se2_batch(one[1:]))
    diff = to_xyyaw(invert(se2_batch(composed)) @ se2_batch(two))
    moving = np.hypot(composed[:, 0], composed[:, 1]) > 1.0
    ratio = np.hypot(two[:, 0], two[:, 1]) / np.maximum(np.hypot(composed[:, 0], composed[:, 1]), 1e-9)
    scale = float(np.mean(ratio[moving])) if moving.any() else math.nan
    return {
        "composition_t_m": float(np.sqrt(np.mean(diff[:, 0] ** 2 + diff[:, 1] ** 2))),
        "composition_yaw_deg": float(np.degrees(np.sqrt(np.mean(wrap_angle(diff[:, 2]) ** 2)))),
        "skip2_scale": scale,
        "mean_step_m": float(np.mean(np.hypot(one[:, 0], one[:, 1]))),
        "direction_deg": direction_bias_deg(one),
        "pairs": int(len(one)),
    }


def check_collapse(shipped: dict, adapted: dict, ratio: float = COLLAPSE_RATIO) -> str | None:
    """A reason to refuse the adapted model, or None: its mean step on the held-out stretch is
    below ``ratio`` × the shipped model's (a mask that keeps only sensor-fixed content reads every
    pair as standing still)."""
    a, s = adapted["mean_step_m"], shipped["mean_step_m"]
    if not (math.isfinite(a) and math.isfinite(s)) or (s > 0.2 and a < ratio * s):
        return (f"the adapted model reads the held-out stretch's steps {a:.2f} m long on average against the shipped "
                f"model's {s:.2f} m: it collapsed toward standing still")
    return None


def base_files(base: str, workdir: Path) -> tuple[Path, Path, dict]:
    """(checkpoint, stream ONNX file, export settings) of the model adapted from: a shipped name
    (its checkpoint and graph, exported the way it ships) or a checkpoint (exported to
    ``workdir`` with the fast search, what every shipped model uses)."""
    from radar_odom.model_zoo import pretrained, pretrained_names, shipped_export

    from .checkpoint import resolve_checkpoint
    from .onnx_export import export_checkpoint

    ckpt = resolve_checkpoint(base)
    if not Path(base).is_file() and base in pretrained_names():
        how = shipped_export(base)
        if how["form"] != "stream":
            raise ConfigError(f"{base} ships in the {how['form']} form; adapt a stream-form model")
        return ckpt, Path(pretrained(base)), {"search": how["search"], "search_settings": how["settings"]}
    onnx_path = workdir / f"{ckpt.stem}-base.onnx"
    export_checkpoint(ckpt, onnx_path, search="fast", verify=False)
    return ckpt, onnx_path, {"search": "fast", "search_settings": None}


def holdout_split(n: int, fraction: float) -> int:
    """Index of the first held-out sweep of ``n``: the last ``fraction`` (at least `MIN_HELD`
    sweeps, at least `MIN_TRAIN` left to train on)."""
    if not 0.0 < fraction < 1.0:
        raise ConfigError(f"holdout fraction must be in (0, 1), got {fraction!r}")
    held = max(MIN_HELD, int(round(fraction * n)))
    if n - held < MIN_TRAIN:
        raise SequenceError(f"{n} sweeps: holding out {held} leaves fewer than {MIN_TRAIN} to adapt on")
    return n - held


def reference_kitti(rec: Recording, start: int, runs: dict, whole_poses: np.ndarray) -> tuple[dict, str]:
    """KITTI figures of each held-out run in ``runs`` (name → absolute poses [M, 3, 3] of sweeps
    ``start:``) against the recording's reference, and a one-line note; ({}, why) without one.
    A GNSS/INS track is aligned in clock on ``whole_poses`` (the shipped runtime over every sweep)
    and in heading as ``radar-odom run`` aligns it."""
    from radar_odom.evaluation.metrics import kitti_lengths_for, kitti_metrics, path_lengths_m, step_biases
    from radar_odom.evaluation.reference import gnss_reference
    from radar_odom.se2 import chain_relative

    seq = rec.sequence
    try:
        if getattr(seq, "gt_relative", None) is not None:
            if rec.skipped:
                return {}, "reference not used: some sweeps were unreadable (their ground-truth rows do not line up)"
            first = rec.first + start
            gt = chain_relative(np.asarray(seq.gt_relative, dtype=np.float64)[first: rec.first + len(rec.scans) - 1])
            note = "the recording's own ground truth"
        else:
            _, info, _ = gnss_reference(seq.reference, rec.timestamps_us, whole_poses)
            gt, _, note = gnss_reference(seq.reference, rec.timestamps_us[start:], None, info["clock_offset_s"])
        length_m = float(path_lengths_m(gt)[-1])
        lengths = kitti_lengths_for(length_m)
        if lengths is None:
            return {}, f"reference not used: the held-out stretch ({length_m:.0f} m) is too short for KITTI segments"
        out = {}
        for name, poses in runs.items():
            m = kitti_metrics(gt, poses, step=4, lengths=lengths, pooling="segments")
            st = step_biases(gt, poses)
            out[name] = {"translation_percent": float(m["translation_percent"]),
                         "rotation_deg_per_m": float(m["rotation_deg_per_m"]),
                         "step_scale": float(st["scale"]), "direction_deg": float(st["direction_deg"]),
                         "yaw_slope": float(st["yaw_slope"])}
        return out, note
    except (RadarOdomError, ValueError) as exc:
        return {}, f"reference not used: {exc}"


def check_adapt_config(cfg: AdaptConfig, output) -> None:
    """`ConfigError` / `OutputError` for settings `adapt` cannot work with, named as the command line names them,
    before anything is read: a non-finite or non-positive budget or learning rate, a real share or held-out share
    outside (0, 1), a pair span below 1 sweep, ``resume`` with no state to resume from, an output that is not an
    .onnx file or cannot be written."""
    from radar_odom.budgets import check_budget_minutes
    from radar_odom.outputs import check_output_path

    from .train import state_path

    def positive(value, flag):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ConfigError(f"{flag} must be a positive number, got {value!r}")

    positive(cfg.minutes, "--minutes")
    check_budget_minutes(cfg.minutes, "--minutes", allow_zero=False)  # and at most a week
    positive(cfg.lr, "--lr")
    for value, flag in ((cfg.real_fraction, "--real-fraction"), (cfg.holdout_fraction, "--holdout")):
        if not (isinstance(value, (int, float)) and 0.0 < value < 1.0):
            raise ConfigError(f"{flag} is a share, strictly between 0 and 1, got {value!r}")
    for value, flag in ((cfg.max_skip, "--max-skip"), (cfg.epochs, "--epochs")):
        if not (isinstance(value, int) and value >= 1):
            raise ConfigError(f"{flag} must be a whole number ≥ 1, got {value!r}")
    output = Path(output)
    if output.suffix != ".onnx":
        raise ConfigError(f"-o {output}: the adapted model is an ONNX file; name it *.onnx")
    check_output_path(output, "-o")
    if cfg.resume and not state_path(output.with_suffix(".pt")).is_file():
        raise ConfigError(f"--resume: no interrupted run to continue ({state_path(output.with_suffix('.pt'))} does "
                          "not exist); run without --resume")


def labels_on_ranks(d, n: int, label_one, label_all=None) -> list:
    """Every recording's pseudo-labels ``label_one(k)`` / ``label_all()[k]``, k < ``n``, on every rank of
    ``d`` (`train.Dist`): recording k is labelled by rank k mod world (``label_all``, a Ray labeller that is
    parallel already, by rank 0 alone), then gathered, so no recording is labelled twice."""
    import torch

    if label_all is not None:
        mine = dict(enumerate(label_all())) if d.main else {}
    else:
        mine = {k: label_one(k) for k in range(d.rank, n, d.world)}
    if d.active:
        parts = [None] * d.world
        torch.distributed.all_gather_object(parts, mine)
        mine = {k: v for part in parts for k, v in part.items()}
    return [mine[k] for k in range(n)]


def adapt(recordings, output, cfg: AdaptConfig, topic: str | None = None, sweeps: slice = slice(None),
          labeller=None, dist=None) -> dict | None:
    """Fine-tune ``cfg.base`` on ``recordings`` (folders or bags, no reference needed), write
    ``output`` (.onnx, the base's search and form), the checkpoint beside it (``.pt``) and a report
    (``.adapt.json``); returns the report. See the module docstring for the method. ``labeller``: None
    labels the recordings one after the other here, else ``labeller(base_onnx, recordings, topic, sweeps)``
    gives every recording's (poses, relative poses) at once (`adapt_labels.ray_labeller`: Ray workers).
    ``dist`` (`train.Dist`, under torchrun): every rank trains on its shard; only rank 0 exports, scores and
    writes; the other ranks return None."""
    workdir = Path(tempfile.mkdtemp(prefix="radar-odom-adapt-"))  # the base's and candidates' files, never kept
    try:
        return _adapt(recordings, output, cfg, topic, sweeps, labeller, dist, workdir)
    finally:  # done, failed or interrupted (Ctrl-C, SIGTERM): what is worth keeping was moved out already
        shutil.rmtree(workdir, ignore_errors=True)


def _adapt(recordings, output, cfg: AdaptConfig, topic, sweeps: slice, labeller, dist, workdir: Path) -> dict | None:
    """`adapt`'s work, its temporary files in ``workdir`` (removed by `adapt`)."""
    import torch

    from .checkpoint import read_checkpoint_dict, write_checkpoint_dict
    from .data import Drive, build_drives, check_seed_policy, scan_to_cartesian, sensor_specs
    from .onnx_export import export_checkpoint
    from .train import Dist, TrainConfig, main_first, train

    d = dist or Dist()
    t0 = time.perf_counter()
    output = Path(output)
    check_adapt_config(cfg, output)  # every refusal before the recordings are read and labelled (minutes)
    ckpt_out = output.with_suffix(".pt")
    report_path = output.with_suffix(".adapt.json")
    check_seed_policy(cfg.sim_seeds, "train")
    threads = cfg.threads or max(1, (os.cpu_count() or 1) // d.world)
    base_ckpt, base_onnx, export_how = base_files(cfg.base, workdir)
    base = read_checkpoint_dict(base_ckpt)
    from radar_odom.profiles import GridProfile

    profile = GridProfile.from_dict(base["profile"])

    recs = [read_recording(r, topic, sweeps) for r in recordings]
    labelled = labels_on_ranks(
        d, len(recs), lambda k: run_runtime(base_onnx, recs[k].scans, threads, desc=f"pseudo-labels {recs[k].name}"),
        None if labeller is None else lambda: labeller(base_onnx, recordings, topic, sweeps))
    drives, held = [], []
    for k, rec in enumerate(recs):
        rec.poses, rel = labelled[k]
        labels = vehicle_chord(rel) if cfg.vehicle_prior else rel
        cut = holdout_split(len(rec.scans), cfg.holdout_fraction)
        images = np.stack([scan_to_cartesian(s, profile).astype(np.float16)
                           for s in progress(rec.scans, desc=f"grid {rec.name}", unit="sweep")])
        drives.append(Drive(f"adapt:{rec.name}[:{cut}]", images[:cut], labels[: cut - 1].astype(np.float32)))
        held.append(Drive(f"adapt:{rec.name}[{cut}:]", images[cut:], labels[cut:].astype(np.float32)))
        rec.cut, rec.rel = cut, rel
    sim_t0 = time.perf_counter()
    with main_first(d):  # rank 0 fills the drive cache, the others read it
        # the budget covers simulating (at most SIM_SHARE of it; at least one drive) and training (what is left)
        sim = build_drives(profile, sensor_specs(cfg.sim_seeds, cfg.sim_scenarios, cfg.sim_frames, "randomised"),
                           min(2, threads), desc="simulated drives", min_drives=1 if d.main else 0,
                           deadline=sim_t0 + SIM_SHARE * 60.0 * cfg.minutes if d.main else -math.inf)
    prep_s = time.perf_counter() - t0
    remaining = training_minutes(cfg.minutes, time.perf_counter() - sim_t0)
    ends = time.strftime("%H:%M", time.localtime(time.time() + 60 * remaining))
    if d.main:
        print(f"adapt: {sum(len(r.scans) for r in recs)} sweeps read and labelled in {prep_s / 60:.1f} min; training "
              f"{remaining:.0f} min at most (ends by {ends}), then the held-out report", file=sys.stderr, flush=True)
    tcfg = TrainConfig(
        output=str(ckpt_out), profile=profile, lr=cfg.lr, lr_decay=1.0, batch=cfg.batch, pose_loss="ce",
        epochs=cfg.epochs, minutes=remaining, threads=threads, init_from=None if cfg.resume else str(base_ckpt),
        resume=cfg.resume, real_fraction=cfg.real_fraction, real_max_skip=cfg.max_skip, seed=cfg.seed,
        info={**cfg.info, "adapt": {k: v for k, v in asdict(cfg).items() if k != "info"}},
    )
    summary = train(tcfg, sim, held, d, real_drives=drives)
    if not d.main:  # rank 0 alone exports, scores and writes
        return None
    # the checkpoint keeps the base's covariance calibration (its profile): no reference to recalibrate on
    ckpt = read_checkpoint_dict(ckpt_out)
    ckpt["train"]["adapted_from"] = Path(str(cfg.base)).name
    if "calibration" in base:
        ckpt["calibration"] = base["calibration"]
    write_checkpoint_dict(ckpt_out, ckpt)
    tuned = workdir / f"fine-tuned-{output.name}"
    export_checkpoint(ckpt_out, tuned, search=export_how["search"], search_settings=export_how["search_settings"],
                      verify=True)
    torch.set_num_threads(threads)
    # two candidates, each with the radar's mount yaw measured from its own steps on the training part:
    # the base's masker and the fine-tuned one
    base_mounted = workdir / f"base-{output.name}"
    shutil.copyfile(base_onnx, base_mounted)
    mounts = {"base": None, "fine-tuned": None}
    if cfg.vehicle_prior:
        mounts["base"] = mount_yaw_from(np.concatenate([r.rel[: r.cut - 1] for r in recs]))
        mounts["fine-tuned"] = mount_yaw_from(np.concatenate(
            [run_runtime(tuned, r.scans[: r.cut], threads, desc=f"mount yaw {r.name}")[1] for r in recs]))
    files = {"base": base_mounted, "fine-tuned": tuned}
    for name, path in files.items():
        if mounts[name] is not None:
            set_mount_yaw(path, mounts[name])
    ckpt["train"]["adapt"] = {**ckpt["train"].get("adapt", {}), "mount_yaw_rad": mounts["fine-tuned"]}
    write_checkpoint_dict(ckpt_out, ckpt)  # `radar-odom export` of it carries the mount yaw on

    report = {"format": ADAPT_FORMAT, "base": Path(str(cfg.base)).name, "output": output.name,
              "sweeps": f"{'' if sweeps.start is None else sweeps.start}:{'' if sweeps.stop is None else sweeps.stop}",
              "config": {k: v for k, v in asdict(cfg).items() if k != "info"},
              "mount_yaw_deg": {k: None if v is None else math.degrees(v) for k, v in mounts.items()},
              "train": {k: summary.get(k) for k in ("steps", "best_epoch", "best_val", "epochs_run", "wall_s",
                                                     "stopped_by_budget")},
              "recordings": []}
    refused, consistency = [], {"base": [], "fine-tuned": []}
    for rec in recs:
        held_scans = rec.scans[rec.cut:]
        sc = {"shipped": self_consistency(base_onnx, held_scans, threads),
              **{name: self_consistency(path, held_scans, threads) for name, path in files.items()}}
        for name in consistency:
            consistency[name].append(sc[name])
        entry = {"name": rec.name, "sweeps": len(rec.scans), "first": rec.first, "unreadable": rec.skipped,
                 "held_out_from": rec.cut, "pseudo_label_direction_deg": direction_bias_deg(rec.rel),
                 "self_consistency": sc}
        why = check_collapse(sc["shipped"], sc["fine-tuned"])
        if why:
            refused.append(f"{rec.name}: {why}")
        if has_reference(rec.sequence):
            runs = {"shipped": run_runtime(base_onnx, held_scans, threads, desc="held out, shipped")[0],
                    **{name: run_runtime(path, held_scans, threads, desc=f"held out, {name}")[0]
                       for name, path in files.items()}}
            entry["kitti"], entry["reference"] = reference_kitti(rec, rec.cut, runs, rec.poses)
        else:
            entry["reference"] = "no reference in the recording"
        report["recordings"].append(entry)
    choice, reason = choose_masker(consistency, cfg.keep, refused)
    report.update(kept=choice, kept_because=reason, refused=refused, wall_s=time.perf_counter() - t0)
    if choice == "base":  # the checkpoint beside the graph holds what the graph holds; the fine-tune is kept aside
        os.replace(ckpt_out, output.with_suffix(".fine-tuned.pt"))
        kept = dict(base)
        kept["train"] = {**base.get("train", {}), "adapted_from": Path(str(cfg.base)).name,
                         "adapt": {"kept": "base", "because": reason, "mount_yaw_rad": mounts["base"]}}
        write_checkpoint_dict(ckpt_out, kept)
    os.replace(files[choice], output)
    report_path.write_text(json.dumps(report, indent=2) + "\n")
    return report


def choose_masker(consistency: dict, keep: str = "auto", refused=()) -> tuple[str, str]:
    """("base" | "fine-tuned", why): which masker `adapt` writes.

    ``consistency``: per candidate, the `self_consistency` dicts of the held-out stretches.
    ``keep="auto"``: the fine-tuned masker where its held-out matches compose at least as well
    as the base's, in translation and in yaw (summed over recordings), and it did not collapse
    (``refused``); else the base's (both carry their own mount yaw). No reference is needed: a
    matcher whose A→C disagrees more with A→B ∘ B→C is noisier. ``keep`` "base" / "fine-tuned"
    forces the choice (the collapse still refuses the fine-tuned one).
    """
    def total(name: str, key: str) -> float:
        return float(sum(c[key] ** 2 * c["pairs"] for c in consistency[name]))

    if refused:
        return "base", "the fine-tuned masker collapsed toward standing still: " + "; ".join(refused)
    if keep in ("base", "fine-tuned"):
        return keep, f"--keep {keep}"
    worse = [label for key, label in (("composition_t_m", "translation"), ("composition_yaw_deg", "yaw"))
             if total("fine-tuned", key) > total("base", key)]
    if worse:
        return "base", (f"the fine-tuned masker's held-out matches compose worse in {' and '.join(worse)} than the "
                        "base's (A→C against A→B∘B→C)")
    return "fine-tuned", "its held-out matches compose at least as well as the base's, in translation and yaw"


def format_report(report: dict) -> str:
    """The report as lines: the choice, the mount yaw, and per recording the held-out
    self-consistency and KITTI (shipped → base + mount → fine-tuned + mount)."""
    mounts = report["mount_yaw_deg"]

    def mount_text(name):
        m = mounts.get(name)
        return "not measured (too few straight steps, or --no-vehicle-prior)" if m is None else f"{m:+.2f}°"

    lines = [f"adapt {report['base']} → {report['output']} in {report['wall_s'] / 60:.1f} min: fine-tuned "
             f"{report['train']['steps']} steps (best epoch {report['train']['best_epoch']}); wrote the "
             f"{report['kept']} masker ({report['kept_because']})",
             f"radar mount yaw: {mount_text('base')} from the base's steps, {mount_text('fine-tuned')} from the "
             "fine-tuned model's (matches are turned by it)"]
    names = ("shipped", "base", "fine-tuned")
    for r in report["recordings"]:
        sc = r["self_consistency"]
        lines.append(f"{r['name']}: held out sweeps {r['held_out_from']}–{r['sweeps'] - 1} "
                     f"({sc['base']['pairs']} pairs)")
        heads = ("shipped", "base + mount", "fine-tuned + mount")
        lines.append(f"  {'self-consistency (graph alone)':34s} " + " ".join(f"{h:>20s}" for h in heads))
        for key, label, fmt in (("composition_t_m", "A→C vs A→B∘B→C, m RMS", ".3f"),
                                ("composition_yaw_deg", "A→C vs A→B∘B→C, ° RMS", ".3f"),
                                ("skip2_scale", "|A→C| / |A→B∘B→C|", ".3f"),
                                ("direction_deg", "straight steps vs travel, °", "+.2f"),
                                ("mean_step_m", "mean step, m", ".3f")):
            lines.append(f"  {label:34s} " + " ".join(f"{format(sc[n][key], fmt):>20s}" for n in names))
        if r.get("kitti"):
            k = r["kitti"]
            lines.append("  KITTI against the reference: translation % "
                         + " / ".join(f"{k[n]['translation_percent']:.2f}" for n in names)
                         + ", rotation °/m " + " / ".join(f"{k[n]['rotation_deg_per_m']:.4f}" for n in names)
                         + " (" + " / ".join(names) + ")")
        elif "reference" in r:
            lines.append(f"  KITTI: {r['reference']}")
    return "\n".join(lines)

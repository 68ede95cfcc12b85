"""Training the masker (paper Alg. 1) and the two baselines, on one process or under torchrun.

Objectives
----------
* ``pose`` (the paper's, default): MSE between the soft-argmax pose and the ground truth. The
  paper minimises ``‖p̄ − p‖²`` with metres and radians mixed, which at our grids lets the yaw
  term vanish (a 0.5° yaw error is 0.0087 rad against translation errors of tenths of a
  metre). We measure each component in *grid cells* instead::

      loss = mean_batch[ ((x̂ − x)² + (ŷ − y)²) / res²  +  yaw_weight · ((ψ̂ − ψ) / δψ)² ]

  with ``res`` the profile's m/px and ``δψ`` its rotation step, so one cell of error costs the
  same on every axis and the same learning rate suits every resolution (``yaw_weight`` = 1).
* ``pose`` with ``--pose-loss ce``: cross-entropy of ``softmax(β·C)`` against the true pose
  spread over its neighbouring candidates (`pose_cross_entropy`). On the simulator the
  paper's MSE barely moves in a CPU budget: masks start nearly closed, the soft-argmax is flat
  and its mean sits at zero motion, where raw correlation also sits (clutter and followers
  static in the sensor frame). Probes on cart-0.8, batch 8, lr 1e-3, 24 validation pairs:
  MSE at β=1 did not move in 60 steps; CE at β=1 opened the masks to 0.99 in 60 steps (the
  raw baseline, sigmoid saturated); CE at β=10 kept masks near 0.1 and reached a validation
  pose error of 3.3–3.9 cells² against raw's 4.5 within 200 steps (noisy).
* ``masks`` (``--supervised-masks``, the paper's mask-supervision baseline): binary cross
  entropy between the predicted mask and the simulator's static-world label on the Cartesian
  grid, no pose loss.
* ``raw`` (mask ≡ 1) and ``cfar`` (the classical CFAR mask on the normalised sweep,
  `cfar.CFARMask`: for a new radar without ground truth to train on): nothing to train; a
  checkpoint without weights is still written (with its validation loss) so every baseline is
  evaluated, calibrated and exported the same way.

Optimiser: Adam. The paper used lr 1e-5, batch 5, for days on a GPU; on 2 CPU cores we use
lr 1e-3 decayed by ``lr_decay`` per epoch, batch 8 (see ``radar-odom train --help``).
The best checkpoint by validation loss is kept; ``<out>.state.pt`` (optimiser, epoch, RNG,
history) lets ``--resume`` continue; ``<out>.log.json`` and ``<out>.loss.png`` sit beside it.

Distributed: under ``torchrun --nproc_per_node=N`` (env ``WORLD_SIZE`` > 1) each process
trains on its `DistributedSampler` shard inside `DistributedDataParallel` (gloo on CPU,
nccl on CUDA); only rank 0 writes files; a time budget stops all ranks at the same step.
"""
from __future__ import annotations

import json
import math
import os
import sys
import time
from collections.abc import Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from radar_odom._progress import progress
from radar_odom.profiles import GridProfile

from .checkpoint import CheckpointError, provenance_command, save_checkpoint
from .data import NO_AUGMENT, Augment, DataSpecError, Drive, PairDataset
from .distil import MASK_LOSS_TEXT, mask_loss

STATE_FORMAT = "radar-odom-train-state/1"
STATE_KEYS = ("profile", "objective", "model", "optimizer", "epoch", "step", "best_val", "best_epoch", "history",
              "steps", "wall_s", "rng")  # what a resume reads from the state
TRAINING_FREE = ("raw", "cfar")  # maskings with no weights: `train` only describes them
POSE_LOSSES = ("mse", "ce", "ce+mse")
TRAIN_SEARCHES = ("exhaustive", "decoupled")
DEFAULT_PROFILE = "cart-0.8"  # `radar-odom train --profile` when none is given (and no --distill-from)
_MSE_TEXT = "mean[((dx^2+dy^2)/res^2) + yaw_weight*(dyaw/rotation_step)^2] (grid cells^2)"
_CE_TEXT = "cross-entropy of softmax(beta_pose*C) against the trilinear gt target"
# how a --minutes budget is spent (`run_from_args`, `train`): the training drives are simulated within its first
# SIM_TRAIN_SHARE, the validation drives within SIM_VAL_SHARE more (at least one of each, however long), one
# validation pass scores as many pairs as fit in VAL_PASS_SHARE of it, and the training stops early enough for the
# last pass to end by the deadline; a pass that would end beyond it by more than the grace is skipped
SIM_TRAIN_SHARE = 0.4
SIM_VAL_SHARE = 0.1
VAL_PASS_SHARE = 0.1
GRACE_S, GRACE_SHARE = 5.0, 0.02  # the grace: max(5 s, 2 % of the budget)
FINISH_S = 2.0  # kept after the last validation for the final record, log and loss plot


@dataclass
class TrainConfig:
    """Everything a run depends on (saved into the checkpoint's ``train`` record)."""

    output: str
    profile: GridProfile
    masking: str = "learned"  # "learned" | "raw" | "cfar"
    supervised_masks: bool = False
    epochs: int = 30
    minutes: float | None = None  # wall-clock budget for this invocation (stops mid-epoch)
    started: float | None = None  # time.perf_counter() the budget counts from (None: when `train` starts)
    lr: float = 1e-3
    lr_decay: float = 0.9  # multiplicative, per epoch
    batch: int = 8
    yaw_weight: float = 1.0
    pose_loss: str = "mse"  # "mse" (paper) | "ce" | "ce+mse", see pose_cross_entropy
    search: str = "exhaustive"  # "exhaustive" (the volume of every candidate) | "decoupled" (see Objective)
    grad_clip: float = 100.0  # on the global gradient norm; a rare peaked volume can spike it
    augment: Augment = field(default_factory=Augment)
    seed: int = 0
    threads: int | None = None
    resume: bool = False
    init_from: str | None = None  # start from another checkpoint's weights (same U-Net shape)
    symmetric_masker: bool = False  # masker kernels kept left/right symmetric (`symmetry.constrain_left_right_`)
    distill_from: str | None = None  # a teacher checkpoint: train the masker to its mirror-averaged masks (`distil`)
    distill_pose_weight: float = 0.0  # with distill_from: weight of the pose cross-entropy added to the mask MSE
    steps_per_epoch: int | None = None  # cap (None: a full pass over the training pairs)
    real_fraction: float = 0.25  # share of real pairs in the training set when real drives are given
    real_max_skip: int = 4  # real pairs (k, k + s) for s = 1 … this (`real_pairs.SkipPairs`)
    info: dict = field(default_factory=dict)  # provenance: command, seeds, scenarios, data...

    @property
    def objective(self) -> str:
        if self.masking in TRAINING_FREE:
            return self.masking
        if self.distill_from:
            return "distil"
        return "masks" if self.supervised_masks else "pose"


def state_path(output) -> Path:
    """``model.pt`` -> ``model.state.pt``: the resume file beside a checkpoint."""
    p = Path(output)
    return p.with_name(p.stem + ".state.pt")


def _unusable_state(sp: Path, output, exc: BaseException) -> str:
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    detail = f"{type(exc).__name__}: {lines[0][:160]}" if lines else type(exc).__name__
    best = Path(output)
    kept = f"the best checkpoint {best} is left as it is" if best.is_file() else "no best checkpoint was written yet"
    return (f"{sp}: the resume state cannot be read ({detail}): it is truncated or not a training state; "
            f"delete it and train again without --resume ({kept})")


def read_resume_state(output) -> dict:
    """The resume state beside the checkpoint ``output`` (`state_path`), read with ``weights_only=True``.
    `CheckpointError` in one line naming the file and what to do: none there, or one that cannot be read
    (truncated by a full disk, garbage: torch's own RuntimeError / UnpicklingError) or is not a training
    state. The best checkpoint itself is never touched here."""
    sp = state_path(output)
    if not sp.exists():
        raise CheckpointError(f"{sp}: no resume state to continue from; run without --resume first")
    try:
        st = torch.load(sp, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises RuntimeError, pickle's UnpicklingError, EOFError, ...
        raise CheckpointError(_unusable_state(sp, output, exc)) from None
    if not isinstance(st, dict) or st.get("format") != STATE_FORMAT:
        raise CheckpointError(f"{sp}: not a radar-odom training state ({STATE_FORMAT}); delete it and train again "
                              "without --resume, or give -o the checkpoint it belongs to")
    missing = [k for k in STATE_KEYS if k not in st]
    if missing:
        raise CheckpointError(_unusable_state(sp, output, KeyError(f"no {', '.join(missing)}")))
    return st


def log_path(output) -> Path:
    p = Path(output)
    return p.with_name(p.stem + ".log.json")


def plot_path(output) -> Path:
    p = Path(output)
    return p.with_name(p.stem + ".loss.png")


# ----------------------------------------------------------------------------- losses
def default_pose_loss(search: str | None) -> str:
    """The pose loss `radar-odom train` uses when none is asked: cross-entropy (the shipped models'),
    or the soft-argmax error through the decoupled search, the only loss that search takes."""
    return "mse" if search == "decoupled" else "ce"


def pose_loss(
    pred_xyyaw: torch.Tensor, gt_xyyaw: torch.Tensor, profile: GridProfile, yaw_weight: float = 1.0
) -> torch.Tensor:
    """Mean over the batch of the squared pose error in grid cells (module docstring).

    pred, gt: float[B, 3] (x m, y m, yaw rad). Yaw differences are not wrapped: both lie
    within the ±rotation_range search window, far from ±π.
    """
    err = pred_xyyaw - gt_xyyaw
    cells = (err[:, 0] ** 2 + err[:, 1] ** 2) / profile.resolution_m**2
    cells = cells + yaw_weight * (err[:, 2] / profile.rotation_step_rad) ** 2
    return cells.mean()


def mask_bce(masks: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
    """Binary cross entropy between masks [B, W, W] in [0, 1] and static labels [B, W, W]."""
    return F.binary_cross_entropy(masks.clamp(1e-6, 1 - 1e-6), labels)


def pose_target(gt_xyyaw: torch.Tensor, profile: GridProfile) -> torch.Tensor:
    """float[B, K, N, N]: the ground-truth pose spread trilinearly over its 8 neighbouring candidates.

    Candidate (k, i, j) is (x, y, yaw) = ((i − n)·res, (j − n)·res, yaw_k) (``candidate_poses``
    layout); a pose outside the search window is clamped to its border.
    """
    n, k_mid = profile.translation_cells, profile.num_rotations // 2
    size = torch.tensor([profile.num_rotations, 2 * n + 1, 2 * n + 1], dtype=gt_xyyaw.dtype)
    frac = torch.stack(
        [
            gt_xyyaw[:, 2] / profile.rotation_step_rad + k_mid,
            gt_xyyaw[:, 0] / profile.resolution_m + n,
            gt_xyyaw[:, 1] / profile.resolution_m + n,
        ],
        dim=1,
    )
    frac = torch.minimum(frac.clamp(min=0), size - 1)
    lo = frac.floor().clamp(max=size - 2).clamp(min=0)
    t = frac - lo  # [B, 3] position inside the cell, 0..1
    target = torch.zeros(len(gt_xyyaw), *[int(v) for v in size], dtype=gt_xyyaw.dtype)
    b = torch.arange(len(gt_xyyaw))
    for corner in range(8):
        off = torch.tensor([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1], dtype=gt_xyyaw.dtype)
        w = torch.where(off.bool(), t, 1 - t).prod(dim=1)
        idx = (lo + off).long()
        target[b, idx[:, 0], idx[:, 1], idx[:, 2]] += w
    return target


def pose_cross_entropy(volume: torch.Tensor, gt_xyyaw: torch.Tensor, profile: GridProfile) -> torch.Tensor:
    """Mean over the batch of ``−Σ_s t_s log softmax(β·C)_s`` with t = `pose_target` (nats).

    The correlative-matching loss of Barsan et al. 2018 (which the paper builds on): it raises
    the score of the true pose against *every* other candidate, so a mask that feeds a wrong
    peak (clutter static in the sensor frame, vehicles following the ego) is pushed down even
    when the soft-argmax mean is stuck on that peak and the MSE gradient has faded.
    """
    logp = torch.log_softmax(profile.beta_pose * volume.flatten(1), dim=1)
    target = pose_target(gt_xyyaw.to(volume.dtype), profile).to(volume.device).flatten(1)
    return -(target * logp).sum(dim=1).mean()


class Objective(nn.Module):
    """The training loss as one module, so `DistributedDataParallel` wraps a single forward.

    ``forward`` returns ``(loss, pose_mse)``; ``pose_mse`` (grid cells², `pose_loss`) is what
    model selection compares for the pose objectives, None for the mask objective.
    """

    def __init__(self, model: nn.Module, objective: str, yaw_weight: float, pose_loss_kind: str = "mse",
                 search: str = "exhaustive"):
        super().__init__()
        if pose_loss_kind not in POSE_LOSSES:
            raise ValueError(f"pose loss {pose_loss_kind!r}; choose one of {POSE_LOSSES}")
        if search not in TRAIN_SEARCHES:
            raise ValueError(f"search {search!r}; choose one of {TRAIN_SEARCHES}")
        if search == "decoupled" and (pose_loss_kind != "mse" or getattr(model, "dual", False)):
            raise ValueError("training through the decoupled search needs --pose-loss mse (it has no "
                             "candidate volume to take a cross-entropy over) and a single-mode profile")
        self.model = model
        self.objective = objective
        self.yaw_weight = yaw_weight
        self.pose_loss_kind = pose_loss_kind
        # the pose as the exported decoupled graph computes it (yaw from the magnitude spectra, one
        # translation correlation): the loss reaches the masker through both stages
        self.decoupled = None
        if search == "decoupled" and objective == "pose":
            from .decoupled_search import DecoupledPairStep, DecoupledStreamStep

            self.decoupled = DecoupledPairStep(DecoupledStreamStep(model))

    def forward(self, batch: dict):
        if self.objective == "masks":
            if self.model.dual:  # one 2-channel input, both masks out
                masks = self.model.mask(torch.stack([batch["prev"], batch["cur"]], dim=1))
                labels = torch.stack([batch["label_prev"], batch["label_cur"]], dim=1)
            else:  # both sweeps of the pair through the masker as one batch
                masks = self.model.mask(torch.cat([batch["prev"], batch["cur"]]))
                labels = torch.cat([batch["label_prev"], batch["label_cur"]])
            return mask_bce(masks, labels), None
        if self.decoupled is not None:
            pose, _ = self.decoupled(batch["prev"], batch["cur"])
            mse = pose_loss(pose, batch["pose"], self.model.profile, self.yaw_weight)
            return mse, mse
        volume = self.model.correlation_volume(batch["prev"], batch["cur"])
        pose, _ = self.model.pose_from_volume(volume)
        mse = pose_loss(pose, batch["pose"], self.model.profile, self.yaw_weight)
        if self.pose_loss_kind == "mse":
            return mse, mse
        ce = pose_cross_entropy(volume, batch["pose"], self.model.profile)
        return (ce if self.pose_loss_kind == "ce" else ce + mse), mse


class DistilObjective(nn.Module):
    """The distillation loss (`distil`, ``radar-odom train --distill-from``) with `Objective`'s interface:
    ``forward(batch)`` → ``(loss, pose_mse)``. ``model`` is the student (trained); the teacher is frozen
    and not among the optimiser's parameters. ``pose_mse`` (grid cells², `pose_loss`) is computed in eval
    mode (validation) and whenever ``pose_weight`` > 0; None otherwise, so a pure mask step never builds
    the correlation volume."""

    def __init__(self, model: nn.Module, teacher: nn.Module, pose_weight: float = 0.0, yaw_weight: float = 1.0):
        super().__init__()
        if pose_weight < 0:
            raise ValueError(f"pose_weight {pose_weight}: give a weight ≥ 0")
        self.model = model
        self.teacher = teacher
        self.pose_weight = pose_weight
        self.yaw_weight = yaw_weight
        self.objective = "distil"

    def train(self, mode: bool = True):
        super().train(mode)
        self.teacher.eval()  # frozen whatever the student does
        return self

    def forward(self, batch: dict):
        student = self.model
        prev, cur = batch["prev"], batch["cur"]
        if self.pose_weight == 0 and self.training:
            # masks alone: one sweep of each pair is enough (a drive's every sweep is some pair's first,
            # and the swap augmentation picks either), which halves the step
            return mask_loss(student, self.teacher, student.normalise(prev))[0], None
        z = student.normalise(torch.cat([prev, cur]))  # both sweeps of the pair as one batch
        loss, masks = mask_loss(student, self.teacher, z)
        n = len(prev)
        s_prev, s_cur = student._to_features(z[:n], masks[:n]), student._to_features(z[n:], masks[n:])
        corr = student.correlation
        volume = corr.correlate(corr.spectrum(s_prev), corr.spectrum(student.rotator(s_cur)))
        pose, _ = student.pose_from_volume(volume)
        mse = pose_loss(pose, batch["pose"], student.profile, self.yaw_weight)
        if self.pose_weight > 0:
            loss = loss + self.pose_weight * pose_cross_entropy(volume, batch["pose"], student.profile)
        return loss, mse


# ----------------------------------------------------------------------------- distributed
@dataclass
class Dist:
    rank: int = 0
    world: int = 1
    device: torch.device = torch.device("cpu")

    @property
    def main(self) -> bool:
        return self.rank == 0

    @property
    def active(self) -> bool:
        return self.world > 1

    def barrier(self):
        if self.active:
            torch.distributed.barrier()

    def sum(self, values: Sequence[float]) -> list[float]:
        t = torch.tensor(list(values), dtype=torch.float64)
        if self.active:
            torch.distributed.all_reduce(t)
        return t.tolist()

    def any(self, flag: bool) -> bool:
        return self.sum([1.0 if flag else 0.0])[0] > 0


def init_distributed() -> Dist:
    """A `Dist` from torchrun's environment (``RANK``, ``WORLD_SIZE``); single process otherwise."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return Dist()
    import torch.distributed as td

    cuda = torch.cuda.is_available()
    if not td.is_initialized():
        td.init_process_group("nccl" if cuda else "gloo")
    rank = td.get_rank()
    device = torch.device("cpu")
    if cuda:
        local = int(os.environ.get("LOCAL_RANK", "0"))
        torch.cuda.set_device(local)
        device = torch.device("cuda", local)
    return Dist(rank=rank, world=td.get_world_size(), device=device)


def shutdown_distributed(d: Dist) -> None:
    if d.active and torch.distributed.is_initialized():
        torch.distributed.destroy_process_group()


@contextmanager
def main_first(d: Dist):
    """Rank 0 runs the block first (e.g. fills the data cache), then the others."""
    if not d.main:
        d.barrier()
    yield
    if d.main:
        d.barrier()


# ----------------------------------------------------------------------------- the loop
def _to(batch: dict, device) -> dict:
    return {k: v.to(device, non_blocking=True) for k, v in batch.items()}


def _loader(dataset, batch: int, shuffle: bool, d: Dist, seed: int, drop_last: bool):
    from torch.utils.data import DataLoader, DistributedSampler

    sampler = DistributedSampler(
        dataset, num_replicas=d.world, rank=d.rank, shuffle=shuffle, seed=seed, drop_last=False
    )
    drop = drop_last and len(sampler) >= batch
    return DataLoader(dataset, batch_size=batch, sampler=sampler, drop_last=drop, num_workers=0), sampler


@torch.no_grad()
def validation_loss(objective: Objective, dataset: PairDataset, batch: int, d: Dist) -> float:
    """Mean training objective over the validation pairs (each rank a shard, then summed)."""
    return validation_stats(objective, dataset, batch, d)["loss"]


@torch.no_grad()
def validation_stats(objective: Objective, dataset: PairDataset, batch: int, d: Dist,
                     deadline: float | None = None) -> dict | None:
    """``loss``: mean objective over the validation pairs; ``pose_mse``: mean `pose_loss` (pose
    objectives); ``mask_mean``: mean mask value.

    The mask mean watches for the masks drifting fully open (sigmoid saturated at 1 = the raw
    baseline, where gradients vanish) or fully shut.

    ``deadline`` (a `time.perf_counter` value, rank 0's clock): None, the pass abandoned, once it has
    passed before the pass ends (a mean over part of the pairs would not compare with other epochs').
    """
    if len(dataset) == 0:
        return {"loss": float("nan"), "pose_mse": float("nan"), "mask_mean": float("nan")}
    objective.eval()
    idx = list(range(d.rank, len(dataset), d.world))
    total, mse_total, count, mask_sum, mask_n = 0.0, 0.0, 0, 0.0, 0
    shard = -(-len(dataset) // d.world)  # the longest rank's share: every rank checks the clock as often
    for start in range(0, shard, batch):
        if deadline is not None and d.any(d.main and time.perf_counter() > deadline):
            objective.train()
            return None
        if start >= len(idx):
            continue
        items = [dataset[i] for i in idx[start : start + batch]]
        b = _to({k: torch.as_tensor(np.stack([it[k] for it in items])) for k in items[0]}, d.device)
        loss, mse = objective(b)
        total += float(loss) * len(items)
        mse_total += float("nan") if mse is None else float(mse) * len(items)
        count += len(items)
        if objective.model.masker is not None and not objective.model.dual:
            mask_sum += float(objective.model.mask(b["prev"]).mean()) * len(items)
            mask_n += len(items)
    objective.train()
    total, mse_total, count, mask_sum, mask_n = d.sum([total, mse_total, count, mask_sum, mask_n])
    return {
        "loss": total / max(count, 1),
        "pose_mse": mse_total / max(count, 1),
        "mask_mean": mask_sum / mask_n if mask_n else float("nan"),
    }


def _rng_state() -> dict:
    return {"torch": torch.get_rng_state()}


def _set_rng_state(state: dict) -> None:
    if "torch" in state:
        torch.set_rng_state(state["torch"])


class _Pairs:
    """Some pairs of a dataset, by index (a bounded validation set)."""

    def __init__(self, dataset, indices: Sequence[int]):
        self.dataset, self.indices = dataset, [int(i) for i in indices]

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, i: int) -> dict:
        return self.dataset[self.indices[i]]


def _spread(total: int, n: int) -> list[int]:
    """``n`` of ``range(total)``, evenly spaced (every drive, and so every scenario, keeps its share)."""
    return sorted({int(i) for i in np.linspace(0, total - 1, n).round()}) if n < total else list(range(total))


def budget_val_set(objective, val_set, cfg: TrainConfig, d: Dist, deadline: float):
    """The validation pairs of a budgeted run and the seconds one pass over them is expected to take: as many
    pairs, evenly spread over the drives, as one pass scores within `VAL_PASS_SHARE` of the budget (and within
    half the time left), timed on one batch of them; at least that batch. The same pairs every epoch, so the
    epochs compare."""
    n = min(cfg.batch, len(val_set))
    t0 = time.perf_counter()
    validation_stats(objective, _Pairs(val_set, _spread(len(val_set), n)), cfg.batch, d)
    per_pair = d.sum([(time.perf_counter() - t0) / -(-n // d.world) if d.main else 0.0])[0]  # rank 0's clock
    pass_s = min(VAL_PASS_SHARE * 60.0 * cfg.minutes, max(0.0, deadline - time.perf_counter()) / 2)
    keep = int(min(len(val_set), max(n, d.world * pass_s / max(per_pair, 1e-9))))
    subset = val_set if keep == len(val_set) else _Pairs(val_set, _spread(len(val_set), keep))
    return subset, per_pair * -(-keep // d.world)


def _config_record(cfg: TrainConfig) -> dict:
    rec = {
        "objective": cfg.objective,
        "masking": cfg.masking,
        "supervised_masks": cfg.supervised_masks,
        "epochs": cfg.epochs,
        "minutes": cfg.minutes,
        "lr": cfg.lr,
        "lr_decay": cfg.lr_decay,
        "batch": cfg.batch,
        "yaw_weight": cfg.yaw_weight,
        "pose_loss": cfg.pose_loss,
        "search": cfg.search,
        "grad_clip": cfg.grad_clip,
        "augment": asdict(cfg.augment),
        "seed": cfg.seed,
        "steps_per_epoch": cfg.steps_per_epoch,
        "symmetric_masker": cfg.symmetric_masker,
        "distill_pose_weight": cfg.distill_pose_weight,
        "loss": {
            "pose": {"mse": _MSE_TEXT, "ce": _CE_TEXT, "ce+mse": f"{_CE_TEXT} + {_MSE_TEXT}"}[cfg.pose_loss],
            "masks": "BCE(mask, static label)",
            "distil": MASK_LOSS_TEXT
            + (f" + {cfg.distill_pose_weight:g} * {_CE_TEXT}" if cfg.distill_pose_weight else ""),
            "raw": "none",
            "cfar": "none",
        }[cfg.objective],
    }
    rec.update(cfg.info)
    return rec


def train(
    cfg: TrainConfig, train_drives: Sequence[Drive], val_drives: Sequence[Drive], dist: Dist | None = None,
    real_drives: Sequence[Drive] = (),
) -> dict:
    """Train (or, for a `TRAINING_FREE` masking, just describe) a model; returns the run summary.

    ``real_drives`` (real recordings with reference poses, their held-out stretch already cut
    off: `real_pairs.real_drive`) are mixed into the training set (`real_pairs.MixedPairs`,
    ``cfg.real_fraction``), as skip-k pairs with gain and floor randomised.

    Writes ``cfg.output`` (best checkpoint), ``<out>.state.pt``, ``<out>.log.json`` and
    ``<out>.loss.png`` from rank 0. With ``cfg.resume`` it continues from ``<out>.state.pt``.
    """
    from .model import MaskedCorrelator

    d = dist or Dist()
    threads = cfg.threads or max(1, (os.cpu_count() or 1) // d.world)
    torch.set_num_threads(threads)
    torch.manual_seed(cfg.seed)  # same initial weights on every rank (DDP also broadcasts them)

    t_start = time.perf_counter()
    # the budget counts from the command's start (`run_from_args` sets ``started``): the drives it
    # simulated first are part of the time the user was promised
    deadline = None if cfg.minutes is None else (cfg.started or t_start) + 60.0 * cfg.minutes
    with_labels = cfg.objective == "masks"
    train_set = PairDataset(train_drives, augment=cfg.augment, with_labels=with_labels, seed=cfg.seed)
    if real_drives:
        from .real_pairs import GainFloor, MixedPairs, SkipPairs

        if with_labels:
            raise DataSpecError("real recordings carry no static-world labels: --real and --supervised-masks "
                                "cannot be combined")
        real_set = SkipPairs(real_drives, cfg.profile, cfg.real_max_skip, cfg.augment, GainFloor(), cfg.seed)
        train_set = MixedPairs(train_set, real_set, cfg.real_fraction, cfg.seed)
    val_set = PairDataset(val_drives, augment=NO_AUGMENT, with_labels=with_labels, seed=cfg.seed)
    val_asked = len(val_set)
    model = MaskedCorrelator(cfg.profile, masking=cfg.masking, dft="fft").to(d.device)
    record = _config_record(cfg)
    if cfg.objective == "distil":
        from .distil import check_student, load_teacher

        if with_labels or cfg.search != "exhaustive":
            raise DataSpecError("--distill-from trains on the teacher's masks: it cannot be combined with "
                                "--supervised-masks or --search")
        teacher = load_teacher(cfg.distill_from, d.device)
        check_student(cfg.profile, teacher.profile)
        objective = DistilObjective(model, teacher, cfg.distill_pose_weight, cfg.yaw_weight)
        record["distill_from"] = Path(cfg.distill_from).name  # no build-machine paths in a checkpoint
    else:
        objective = Objective(model, cfg.objective, cfg.yaw_weight, cfg.pose_loss, cfg.search)
    val_s = 0.0  # seconds one validation pass is expected to take (under a budget: timed)
    if deadline is not None and len(val_set):  # a pass that fits the budget's share, timed on one batch
        val_set, val_s = budget_val_set(objective, val_set, cfg, d, deadline)
    grace = None if deadline is None else max(GRACE_S, GRACE_SHARE * 60.0 * cfg.minutes)
    if deadline is not None and d.main and cfg.objective not in TRAINING_FREE:
        _pyplot()  # the loss plot's import, paid for now rather than after the deadline
    record.update(
        world_size=d.world,
        threads_per_rank=threads,
        torch=torch.__version__,
        train_pairs=len(train_set),
        real_pairs=len(train_set.real) if real_drives else 0,
        real_drives=[x.name for x in real_drives],
        val_pairs=len(val_set),
        val_pairs_asked=val_asked,  # more than val_pairs where the budget bounded the validation set
        train_drives=[x.name for x in train_drives],
        val_drives=[x.name for x in val_drives],
    )

    if cfg.objective in TRAINING_FREE:
        val = validation_stats(objective, val_set, cfg.batch, d)["pose_mse"]
        note = {
            "raw": "raw scans: mask ≡ 1, no weights",
            "cfar": "cell-averaging CFAR mask on the normalised sweep, no weights",
        }[cfg.masking]
        record.update(
            best_val=val, best_epoch=0, epochs_run=0, steps=0, wall_s=time.perf_counter() - t_start, note=note
        )
        if d.main:
            save_checkpoint(cfg.output, model, cfg.masking, train=record)
            _write_log(cfg.output, record, [], [])
        return record

    if not any(p.requires_grad for p in model.parameters()):
        raise ValueError(f"masking={cfg.masking!r} has no trainable weights; use masking='learned'")
    if cfg.init_from and not cfg.resume:
        _init_weights(model, cfg.init_from)
    if cfg.init_from:  # a resume (same arguments) keeps saying where the weights started
        record["init_from"] = Path(cfg.init_from).name  # no build-machine paths in a checkpoint
    if cfg.symmetric_masker:
        # after the init (plain weight names) and before a resume (parametrized names) and the
        # optimiser (which must hold the parametrization's stored tensors)
        from .symmetry import constrain_left_right_

        constrain_left_right_(model.masker)
        record["masker_symmetry"] = "left-right: every kernel constrained to (W + W.flip(-1))/2 in training (issue 41)"
    params = [p for p in model.parameters() if p.requires_grad]
    optim = torch.optim.Adam(params, lr=cfg.lr)
    history: list[dict] = []
    steps_log: list[list[float]] = []  # [global step, loss]
    start_epoch, step, best_val, best_epoch, wall_before = 0, 0, math.inf, -1, 0.0

    if cfg.resume:
        sp = state_path(cfg.output)
        st = read_resume_state(cfg.output)
        # compared as profiles, so a state saved before GridProfile gained a field (read back with
        # that field's default) still resumes; any field that differs refuses, and is named
        saved = GridProfile.from_dict(st["profile"])
        if saved != cfg.profile or st["objective"] != cfg.objective:
            diff = [f for f, v in asdict(cfg.profile).items() if asdict(saved).get(f) != v]
            raise CheckpointError(
                f"{sp}: was made for profile {st['profile'].get('name')!r} / objective {st['objective']!r} "
                f"(differing profile fields: {', '.join(diff) or 'none'}); "
                f"this run asks for {cfg.profile.name!r} / {cfg.objective!r} — resume with the same settings"
            )
        if bool(st.get("symmetric_masker", False)) != cfg.symmetric_masker:
            raise CheckpointError(
                f"{sp}: was trained {'with' if st.get('symmetric_masker') else 'without'} --symmetric-masker; "
                "resume with the same settings"
            )
        try:  # a state of the right format that is still not whole (edited, or written by a broken build)
            model.load_state_dict(st["model"])
            optim.load_state_dict(st["optimizer"])
            start_epoch, step = int(st["epoch"]), int(st["step"])
            best_val, best_epoch = float(st["best_val"]), int(st["best_epoch"])
            history, steps_log = list(st["history"]), [list(x) for x in st["steps"]]
            wall_before = float(st["wall_s"])
            _set_rng_state(st["rng"])
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise CheckpointError(_unusable_state(sp, cfg.output, exc)) from None
        record["best_val_loss"] = next((h["val_loss"] for h in history if h["epoch"] == best_epoch), math.nan)

    net = objective
    if d.active:
        from torch.nn.parallel import DistributedDataParallel as DDP

        net = DDP(objective, device_ids=None if d.device.type == "cpu" else [d.device.index])
    loader, sampler = _loader(train_set, cfg.batch, True, d, cfg.seed, drop_last=True)
    n_steps = len(loader) if cfg.steps_per_epoch is None else min(len(loader), cfg.steps_per_epoch)
    if n_steps == 0:
        raise DataSpecError(
            f"no training step fits: {len(train_set)} training pairs for batch {cfg.batch} "
            f"on {d.world} process(es); give more drives or --frames, or a smaller --batch"
        )

    def out_of_time(reserve: float) -> bool:
        """Whether the budget ends within ``reserve`` seconds (rank 0's clock decides, for every rank)."""
        return deadline is not None and d.any(d.main and time.perf_counter() + reserve > deadline)

    stop = False
    epoch = start_epoch
    for epoch in range(start_epoch, cfg.epochs):
        # a budget spent during the previous epoch's validation ends the run here, rather than
        # one step into a new epoch followed by a whole validation pass
        if epoch > start_epoch and out_of_time(val_s + FINISH_S):
            stop = True
            break
        lr = cfg.lr * cfg.lr_decay**epoch
        for g in optim.param_groups:
            g["lr"] = lr
        sampler.set_epoch(epoch)
        train_set.set_epoch(epoch)
        bar = progress(total=n_steps, desc=f"epoch {epoch + 1}/{cfg.epochs}", unit="step", disable=not d.main)
        running, total, count = None, 0.0, 0
        net.train()
        for i, batch in enumerate(loader):
            if i >= n_steps:
                break
            loss, _ = net(_to(batch, d.device))
            optim.zero_grad(set_to_none=True)
            loss.backward()
            if cfg.grad_clip:
                torch.nn.utils.clip_grad_norm_(params, cfg.grad_clip)
            optim.step()
            value = float(loss.detach())
            if not math.isfinite(value):
                raise FloatingPointError(f"training loss became {value} at step {step}; lower --lr")
            step += 1
            total, count = total + value, count + 1
            running = value if running is None else 0.9 * running + 0.1 * value
            steps_log.append([step, value])
            bar.update(1)
            bar.set_postfix(loss=f"{running:.3g}", lr=f"{lr:.2g}", refresh=False)  # a log gets a line per interval
            # every rank must take the same number of steps; the time of the validation pass is kept for it
            if out_of_time(val_s + FINISH_S):
                stop = True
                break
        bar.close()
        # under a budget, a pass expected to end beyond its deadline by more than the grace is not begun, and
        # one that passes it is abandoned: the weights are then kept unvalidated (see below)
        stats = None
        if deadline is None or not out_of_time(val_s - grace):
            t_val = time.perf_counter()
            stats = validation_stats(objective, val_set, cfg.batch, d,
                                     deadline=None if deadline is None else deadline + grace)
            val_s = time.perf_counter() - t_val
        validated = stats is not None
        if not validated:
            stop = True
            stats = {"loss": math.nan, "pose_mse": math.nan, "mask_mean": math.nan}
        # pose models are selected by pose error (cells²) whatever loss trained them
        val = stats["loss"] if cfg.objective in ("masks", "distil") else stats["pose_mse"]
        tr = d.sum([total, count])
        wall = wall_before + time.perf_counter() - t_start
        history.append(
            {
                "epoch": epoch + 1,
                "step": step,
                "train_loss": tr[0] / max(tr[1], 1),
                "val_loss": stats["loss"],
                "val_pose_mse": stats["pose_mse"],
                "val_mask_mean": stats["mask_mean"],
                "lr": lr,
                "wall_s": wall,
                "complete": not stop,
                "validated": validated,
            }
        )
        # an epoch cut short by the budget still counts: its weights were validated
        if len(val_set) == 0 or (not validated and not math.isfinite(best_val)):
            # nothing held out, or no time left to validate and no validated weights kept: keep the latest
            improved, best_epoch = True, epoch + 1
        else:
            improved = math.isfinite(val) and val < best_val
            if improved:
                best_val, best_epoch = val, epoch + 1
        if improved:  # the trained objective's value at the kept epoch, said beside the pose error
            record["best_val_loss"] = stats["loss"]
        if d.main:
            if validated:
                said = (f"val {stats['loss']:.4g}  "
                        + (f"val pose mse {stats['pose_mse']:.4g} cells²  " if math.isfinite(stats["pose_mse"]) else "")
                        + f"mask mean {stats['mask_mean']:.3f}{'  (best)' if improved else ''}")
            else:
                said = ("not validated, the budget is spent: "
                        + ("these weights are kept" if improved else f"epoch {best_epoch} stays the best"))
            print(f"epoch {epoch + 1}: train {history[-1]['train_loss']:.4g}  {said}  [{wall / 60:.1f} min]",
                  file=sys.stderr)
            record.update(best_val=best_val, best_epoch=best_epoch, epochs_run=epoch + 1, steps=step, wall_s=wall)
            if improved or not Path(cfg.output).exists():
                save_checkpoint(cfg.output, model, cfg.masking, train=record)
            _save_state(cfg, model, optim, epoch + 1, step, best_val, best_epoch, history, steps_log, wall)
            _write_log(cfg.output, record, history, steps_log)
        if stop:
            break
    record.update(
        best_val=best_val,
        best_epoch=best_epoch,
        epochs_run=history[-1]["epoch"] if history else start_epoch,
        steps=step,
        wall_s=wall_before + time.perf_counter() - t_start,
        stopped_by_budget=stop,
        # the checkpoint holds weights no validation pass scored (the budget ended first)
        kept_unvalidated=bool(history) and not math.isfinite(best_val) and len(val_set) > 0,
    )
    if d.active:
        record.update(_rank_report(d, step, params))
    if d.main:
        _finalise_record(cfg.output, record)
        _write_log(cfg.output, record, history, steps_log)
        _plot(cfg.output, history, steps_log)
    return record


def _finalise_record(output, record: dict) -> None:
    """Rewrite the best checkpoint's ``train`` record with the run's final totals (wall time...)."""
    from .checkpoint import _plain, read_checkpoint_dict, write_checkpoint_dict

    if Path(output).exists():
        ckpt = read_checkpoint_dict(output)
        ckpt["train"] = _plain(record)
        write_checkpoint_dict(output, ckpt)


def _init_weights(model, path) -> None:
    """Load another checkpoint's weights, e.g. a cart-0.8 U-Net into a cart-0.4 model whose
    ``mask_downsample`` = 2 runs its U-Net on the same 0.8 m/px grid."""
    from .checkpoint import read_checkpoint_dict

    ckpt = read_checkpoint_dict(path)
    try:
        model.load_state_dict(ckpt["state_dict"], strict=True)
    except RuntimeError as exc:
        raise CheckpointError(
            f"{path}: its weights do not fit this model (U-Net width/depth/mode differ): "
            f"{str(exc).splitlines()[0][:300]}"
        ) from None


def _rank_report(d: Dist, steps: int, params) -> dict:
    """Steps taken by each rank, and whether all ranks ended with identical weights (DDP's promise)."""
    one_hot = [0.0] * d.world
    one_hot[d.rank] = float(steps)
    flat = torch.cat([p.detach().reshape(-1).double().cpu() for p in params])
    hi, lo = flat.clone(), flat.clone()
    torch.distributed.all_reduce(hi, op=torch.distributed.ReduceOp.MAX)
    torch.distributed.all_reduce(lo, op=torch.distributed.ReduceOp.MIN)
    return {"rank_steps": [int(x) for x in d.sum(one_hot)], "ranks_in_sync": bool(torch.equal(hi, lo))}


def _save_state(cfg, model, optim, epoch, step, best_val, best_epoch, history, steps_log, wall) -> None:
    state = {
        "format": STATE_FORMAT,
        "profile": asdict(cfg.profile),
        "objective": cfg.objective,
        "symmetric_masker": cfg.symmetric_masker,  # the model's state names depend on it
        "model": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "optimizer": optim.state_dict(),
        "epoch": epoch,
        "step": step,
        "best_val": best_val,
        "best_epoch": best_epoch,
        "history": history,
        "steps": steps_log,
        "wall_s": wall,
        "rng": _rng_state(),
    }
    sp = state_path(cfg.output)
    tmp = sp.with_name(f".{sp.name}.tmp")
    torch.save(state, tmp)
    os.replace(tmp, sp)


def _write_log(output, record: dict, history: list, steps_log: list) -> None:
    from .checkpoint import _plain

    payload = {"train": _plain(record), "epochs": history, "steps": steps_log}
    lp = log_path(output)
    lp.parent.mkdir(parents=True, exist_ok=True)
    lp.write_text(json.dumps(payload, indent=1, default=str))


def _pyplot():
    """matplotlib's pyplot on the Agg backend (its first import takes seconds on a loaded machine: a budgeted
    run makes it before training, so the training, not the last plot, pays for it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _plot(output, history: list, steps_log: list) -> Path | None:
    """Loss curve (per-step training loss, smoothed, and per-epoch validation) as a PNG."""
    if not steps_log:
        return None
    plt = _pyplot()

    s = np.asarray(steps_log, dtype=np.float64)
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(s[:, 0], s[:, 1], color="0.8", lw=0.6, label="train (step)")
    k = max(1, len(s) // 50)
    if len(s) >= 2 * k:
        smooth = np.convolve(s[:, 1], np.ones(k) / k, mode="valid")
        ax.plot(s[k - 1 :, 0], smooth, color="C0", label=f"train (mean of {k})")
    if history:
        ax.plot([h["step"] for h in history], [h["val_loss"] for h in history], "o-", color="C3", label="validation")
    ax.set_xlabel("step")
    ax.set_ylabel("loss")
    if np.all(s[:, 1] > 0):
        ax.set_yscale("log")
    ax.set_title(Path(output).name)
    ax.legend()
    fig.tight_layout()
    out = plot_path(output)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


# ----------------------------------------------------------------------------- what the command says
def budget_line(minutes: float | None, resume: bool = False, now: float | None = None) -> str:
    """The line `radar-odom train` starts with: the budget and the wall-clock time it ends at."""
    if minutes is None:
        return "train: no time budget (--minutes 0): runs until --epochs are done"
    end = time.localtime((time.time() if now is None else now) + 60.0 * minutes)
    return (f"train: {minutes:g}-minute budget (--minutes) for all of it (simulating drives within "
            f"{SIM_TRAIN_SHARE + SIM_VAL_SHARE:.0%} of it, training, validating): stops by "
            f"{time.strftime('%H:%M:%S', end)} local time with a checkpoint written; "
            + ("continuing the saved run" if resume else "the same command with --resume continues it"))


def drives_line(train_report: dict, val_report: dict, minutes: float) -> str:
    """What `run_from_args` says after simulating under a budget: how many drives of how many asked, and why
    the rest were left out (`data.build_drives`'s reports)."""
    def count(r, what):
        return f"{r['ready']} of {r['asked']} {what} drive{'s' if r['asked'] != 1 else ''}"

    simulated = train_report["simulated"] + val_report["simulated"]
    cached = train_report["cached"] + val_report["cached"]
    seconds = train_report["seconds"] + val_report["seconds"]
    line = (f"train: {count(train_report, 'training')} and {count(val_report, 'validation')} ready "
            f"({simulated} simulated in {seconds / 60:.1f} min, {cached} from the cache)")
    left = train_report["left_out"] + val_report["left_out"]
    if left:
        line += (f"; {left} left out to keep the {minutes:g}-minute budget (simulating stops at "
                 f"{SIM_TRAIN_SHARE:.0%} of it for the training drives, {SIM_VAL_SHARE:.0%} more for validation; "
                 "the drives simulated are cached, so --resume or a longer --minutes adds more)")
    return line


def final_line(output, summary: dict, profile: GridProfile, budget_minutes: float | None = None) -> str:
    """The command's last line: which number is the pose error (what picks the best epoch, grid
    cells²) and which the validation loss (the trained objective), with units, and why it stopped."""
    objective = summary.get("objective", "pose")
    best, epoch = summary.get("best_val", float("nan")), summary.get("best_epoch")
    steps, wall = summary.get("steps", 0), summary.get("wall_s", 0.0) / 60
    cell = (f"1 cell = {profile.resolution_m:g} m in x and y, {math.degrees(profile.rotation_step_rad):g}° in yaw")
    if objective == "masks":
        what = f"best validation loss {best:.4g} (mask BCE against the static labels; epoch {epoch})"
    elif objective == "distil":
        what = (f"best validation loss {best:.4g} (mask MSE against the teacher's mirror-averaged masks"
                + (", plus the weighted pose cross-entropy" if summary.get("distill_pose_weight") else "")
                + f"; epoch {epoch})")
    elif objective in TRAINING_FREE:
        what = (f"validation pose error {best:.4g} cells² (mean squared pose error in grid cells, {cell}); "
                f"nothing trained ({objective} masking)")
    else:
        loss = summary.get("best_val_loss", float("nan"))
        what = (f"best validation pose error {best:.4g} cells² at epoch {epoch} (mean over the validation pairs "
                f"of the squared pose error in grid cells, {cell}: {math.sqrt(best):.2g} cells RMS), "
                f"validation loss {loss:.4g} there ({summary.get('pose_loss', 'mse')}, the trained objective)"
                if math.isfinite(best) else "no validation pose error (no validation pairs)")
    if summary.get("kept_unvalidated"):
        what = (f"the weights of epoch {epoch}, not validated: the {budget_minutes:g}-minute budget ended before "
                "a validation pass could (--resume, or a longer --minutes, validates)")
    asked, used = summary.get("val_pairs_asked"), summary.get("val_pairs")
    if asked and used is not None and used < asked and not summary.get("kept_unvalidated"):
        what += (f" (validated on {used} of {asked} validation pairs, evenly spread: what one pass scores in "
                 f"{VAL_PASS_SHARE:.0%} of the budget)")
    why = ""
    if summary.get("stopped_by_budget"):
        why = f"; stopped by the {budget_minutes:g}-minute budget: add --resume to continue"
    return (f"wrote {output}: {what}; {steps} step{'' if steps == 1 else 's'}, {wall:.1f} min{why}. "
            f"Next: radar-odom export {output} (calibrates its covariance first)")


# ----------------------------------------------------------------------------- command line
def resolve_profile(
    text: str, unet_base_channels: int | None = None, unet_depth: int | None = None, beta_pose: float | None = None,
    mask_downsample: int | None = None,
) -> GridProfile:
    """A named profile, or a JSON file of `GridProfile` fields; U-Net, masker-grid and β overrides applied."""
    from radar_odom.profiles import PROFILES, get_profile

    if text in PROFILES:
        profile = get_profile(text)
    elif Path(text).is_file():
        try:
            profile = GridProfile.from_dict(json.loads(Path(text).read_text()))
        except (ValueError, TypeError) as exc:
            raise DataSpecError(f"--profile {text}: not a valid GridProfile JSON file ({exc})") from None
    else:
        raise DataSpecError(f"--profile {text!r}: not a profile name ({', '.join(PROFILES)}) nor a JSON file")
    changes = {}
    if unet_base_channels:
        changes["unet_base_channels"] = unet_base_channels
    if unet_depth:
        changes["unet_depth"] = unet_depth
    if beta_pose:
        changes["beta_pose"] = changes["beta_cov"] = float(beta_pose)  # calibration retunes beta_cov
    if mask_downsample:
        changes["mask_downsample"] = int(mask_downsample)
    try:
        profile = profile.with_(**changes) if changes else profile
    except ValueError as exc:  # e.g. a masker grid the U-Net's depth does not divide
        raise DataSpecError(f"--profile {text} with the overrides given: {exc}") from None
    if profile.input_kind != "cartesian":
        raise DataSpecError(
            f"profile {profile.name!r} takes polar input; training data are Cartesian drives — "
            "polar-input training is not supported by `radar-odom train` yet"
        )
    return profile


def distil_profile(teacher, profile_name: str | None, base_channels: int | None, depth: int | None,
                   mask_downsample: int | None = None) -> GridProfile:
    """The student's profile for ``--distill-from``: the teacher checkpoint's (so grid, band limits and
    read-out are the shipped model's) with the U-Net overrides; ``--profile``, if given, must name it."""
    from .checkpoint import read_checkpoint_dict, resolve_checkpoint
    from .distil import student_profile

    teacher_profile = GridProfile.from_dict(read_checkpoint_dict(resolve_checkpoint(teacher))["profile"])
    if profile_name and profile_name != teacher_profile.name:
        raise DataSpecError(f"--profile {profile_name}: --distill-from {teacher} has profile "
                            f"{teacher_profile.name!r}; the student takes the teacher's (leave out --profile)")
    try:
        return student_profile(teacher_profile, base_channels, depth, mask_downsample)
    except ValueError as exc:
        raise DataSpecError(f"--distill-from {teacher}: the student's profile: {exc}") from None


def _sim_version() -> int:
    from radar_odom.sim import SIMULATOR_VERSION

    return SIMULATOR_VERSION


def _sim_deadline(minutes: float | None, start: float, share: float, d: Dist) -> float | None:
    """Until when `build_drives` may simulate: ``share`` of the budget after ``start``; none without a budget;
    already passed on the ranks after the first (they simulate nothing: rank 0 made the drives ready)."""
    if minutes is None:
        return None
    return start + share * 60.0 * minutes if d.main else -math.inf


def run_from_args(args) -> dict:
    """`radar-odom train`: build the data (rank 0 first, it fills the cache), then `train`."""
    from .data import (
        Augment,
        build_drives,
        check_seed_policy,
        folder_drives,
        parse_seeds,
        sensor_specs,
        sequence_drives,
        split_folders,
    )

    started = time.perf_counter()
    minutes = None if not args.minutes else float(args.minutes)
    if args.minutes is not None:  # ≥ 0 and at most a week: 1e308 overflowed the end-time line
        from radar_odom.budgets import check_budget_minutes
        from radar_odom.errors import ConfigError

        try:
            check_budget_minutes(args.minutes)
        except ConfigError as exc:
            raise DataSpecError(str(exc)) from None
    if args.resume:  # a missing or damaged state is said now, not after the drives are simulated (minutes)
        read_resume_state(args.output)
    d = init_distributed()
    try:
        if d.main:
            print(budget_line(minutes, resume=args.resume), flush=True)
        teacher = getattr(args, "distill_from", None)
        if not (getattr(args, "distill_pose_weight", 0.0) or 0.0) >= 0:
            raise DataSpecError(f"--distill-pose-weight {args.distill_pose_weight}: give a weight ≥ 0")
        if teacher:
            profile = distil_profile(teacher, args.profile, args.unet_base_channels, args.unet_depth,
                                     getattr(args, "mask_downsample", None))
        else:
            profile = resolve_profile(
                args.profile or DEFAULT_PROFILE, args.unet_base_channels, args.unet_depth,
                getattr(args, "beta_pose", None), getattr(args, "mask_downsample", None),
            )
        if args.masking == "cfar" and profile.input_norm == "none":  # said before any data is built
            raise DataSpecError(
                f"--masking cfar needs a profile with input_norm 'floor-scale' (its thresholds "
                f"are in normalised units); profile {profile.name!r} has 'none'"
            )
        labels = bool(args.supervised_masks)
        info = {"command": provenance_command(sys.argv[1:]), "profile_name": profile.name}
        with main_first(d):
            if args.data:
                per_folder = folder_drives(args.data, profile)
                if args.val_data:
                    train_drives = [x for f in per_folder for x in f]
                    val_drives = [x for p in args.val_data for x in sequence_drives(p, profile)]
                else:
                    train_drives, val_drives = split_folders(per_folder)
                info.update(data=[str(p) for p in args.data], val_data=[str(p) for p in (args.val_data or [])])
            else:
                scenarios = [s for s in args.scenarios.split(",") if s]
                seeds, val_seeds = parse_seeds(args.sim_seeds), parse_seeds(args.val_seeds)
                check_seed_policy(seeds, "train")
                check_seed_policy(val_seeds, "val")
                workers = args.workers if d.main else 1
                sensor = getattr(args, "sensor", "randomised")
                val_frames = getattr(args, "val_frames", None) or args.frames
                # under a budget, simulating stops at its share (`build_drives`, at least one drive of each);
                # the other ranks take the drives rank 0 made ready, from the cache, and simulate none
                budget = {} if minutes is None else {"min_drives": 1 if d.main else 0}
                reports = {"train": {}, "val": {}}
                train_drives = build_drives(
                    profile,
                    sensor_specs(seeds, scenarios, args.frames, sensor),
                    workers,
                    with_labels=labels,
                    desc="training drives",
                    deadline=_sim_deadline(minutes, started, SIM_TRAIN_SHARE, d),
                    report=reports["train"],
                    **budget,
                )
                # validation on the Oxford preset: the installation the simulator is calibrated to
                val_drives = build_drives(
                    profile,
                    sensor_specs(val_seeds, scenarios, val_frames, "oxford"),
                    workers,
                    with_labels=labels,
                    desc="validation drives",
                    deadline=_sim_deadline(minutes, time.perf_counter(), SIM_VAL_SHARE, d),
                    report=reports["val"],
                    **budget,
                )
                if minutes is not None and d.main:
                    print(drives_line(reports["train"], reports["val"], minutes), flush=True)
                info.update(
                    sim_seeds=seeds,
                    val_seeds=val_seeds,
                    scenarios=scenarios,
                    frames=args.frames,
                    sensor=sensor,
                    val_sensor="oxford",
                    simulator_version=_sim_version(),
                )
        augment = Augment(
            mirror_p=0.0 if args.no_mirror else 0.5,
            swap_p=0.0 if args.no_swap else 0.5,
            rotate_max_rad=math.radians(args.rotate_deg),
        )
        cfg = TrainConfig(
            output=args.output,
            profile=profile,
            masking=args.masking,
            supervised_masks=labels,
            epochs=args.epochs,
            minutes=minutes,
            started=started,
            lr=args.lr,
            lr_decay=args.lr_decay,
            batch=args.batch,
            yaw_weight=args.yaw_weight,
            pose_loss=getattr(args, "pose_loss", None) or default_pose_loss(getattr(args, "search", None)),
            search=getattr(args, "search", None) or "exhaustive",
            augment=augment,
            seed=args.seed,
            threads=args.threads,
            resume=args.resume,
            init_from=getattr(args, "init_from", None),
            symmetric_masker=getattr(args, "symmetric_masker", False),
            distill_from=teacher,
            distill_pose_weight=getattr(args, "distill_pose_weight", 0.0) or 0.0,
            steps_per_epoch=args.steps_per_epoch,
            real_fraction=getattr(args, "real_fraction", 0.25),
            info=info,
        )
        real = []
        if getattr(args, "real", None):
            from .real_pairs import real_drive

            with main_first(d):
                real = [real_drive(p, profile, args.real_holdout) for p in args.real]
            info.update(real=[Path(p).name for p in args.real], real_holdout=args.real_holdout,
                        real_fraction=args.real_fraction)
        summary = train(cfg, train_drives, val_drives, d, real_drives=real)
        if d.main:
            print(final_line(cfg.output, summary, profile, budget_minutes=cfg.minutes))
        # every rank reaches the end before the process group goes: a rank that tore gloo down while
        # rank 0 still wrote its checkpoint aborted now and then ("terminate called without an active exception")
        d.barrier()
        return summary
    finally:
        shutdown_distributed(d)

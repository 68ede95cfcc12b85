"""Speed–accuracy of each grid resolution and rotation-search setting: a plot and a table.

    python benchmarks/speed_accuracy.py -o bench-speed-accuracy
    python benchmarks/speed_accuracy.py --profiles cart-0.4 --settings c4s2b1 c4s2b2 c4s1b1 \\
        --seeds 5000-5001 --frames 120 --masks labels -o out

For every profile, the exhaustive search (every yaw candidate, `MaskedCorrelator.stream_step`)
and each fast setting (`radar_odom_export.fast_search`, named ``c<coarse factor>s<coarse
stride>b<band half-width>``) run over the same held-out simulated drives (seeds >= 5000, one
drive per scenario and seed):

* accuracy: KITTI translational (%) and rotational (deg/m) error over ``--lengths`` metre
  segments every 4 frames, pooled over all drives, plus the mean per-step errors;
* speed: the exported graph of each search (the same weights) timed in onnxruntime with
  ``--threads`` threads, median over ``--steps`` stream steps on the drives' own sweeps, plus
  the runtime's polar→Cartesian of one sweep: *step* = the two, what the paper times.

Masks (``--masks``): ``checkpoint`` uses the trained checkpoint given by ``--checkpoint
PROFILE=PATH`` (its masker and β); ``raw`` is the raw-scan model (mask ≡ 1); ``labels`` uses the
simulator's static-world labels as external masks, a stand-in for a well-trained masker.
Speed is always measured with the learned-mask graph (the U-Net included), untrained weights
unless a checkpoint is given: weights do not change the time.

Writes ``OUT/speed_accuracy.json``, ``OUT/speed_accuracy.md`` and ``OUT/speed_accuracy.png``.
Results per (profile, setting) are cached in the JSON, so an interrupted run resumes.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

DEFAULT_SETTINGS = {  # the shipped default first (fast_search.DEFAULT_SETTINGS), then neighbours
    "cart-0.8": ["c2s2b2", "c2s1b2", "c2s2b1"],
    "cart-0.4": ["c4s2b2", "c4s2b1", "c4s1b2"],
    "cart-0.2": ["c8s1b2", "c8s1b1", "c4s2b2"],
}


def parse_setting(text: str):
    """``c4s2b1`` → `FastSearchSettings(coarse_factor=4, coarse_stride=2, band_half_width=1)`;
    a ``-bilinear`` suffix selects grid_sample rotation."""
    from radar_odom_export.fast_search import FastSearchSettings

    rotation = "polar"
    if text.endswith("-bilinear"):
        text, rotation = text[: -len("-bilinear")], "bilinear"
    try:
        c, rest = text[1:].split("s")
        s, b = rest.split("b")
        return FastSearchSettings(int(c), int(s), int(b), rotation)
    except ValueError:
        raise SystemExit(f"bad setting {text!r}: write c<factor>s<stride>b<half-width>, e.g. c4s2b1") from None


# ---------------------------------------------------------------------------------------- accuracy
def stream_poses(step, model, drive, use_labels: bool):
    """Relative poses [F-1, 3] of a drive streamed through ``step(cur, state[, mask])``."""
    import torch

    poses = []
    with torch.no_grad():
        images = torch.from_numpy(drive.images.astype(np.float32))
        masks = torch.from_numpy(drive.labels.astype(np.float32)) if use_labels else None
        state = model.initial_state(images[:1], None if masks is None else masks[:1])
        for k in range(1, len(images)):
            extra = () if masks is None else (masks[k : k + 1],)
            pose, _, state = step(images[k : k + 1], state, *extra)
            poses.append(pose[0].double().numpy())
    return np.array(poses)


def accuracy(poses_by_drive, drives, lengths) -> dict:
    from radar_odom.evaluation.metrics import kitti_metrics, relative_pose_errors
    from radar_odom.se2 import chain_relative

    gt = [chain_relative(d.poses_rel.astype(np.float64)) for d in drives]
    est = [chain_relative(p) for p in poses_by_drive]
    km = kitti_metrics(gt, est, step=4, lengths=lengths)
    rel = relative_pose_errors(np.concatenate([d.poses_rel for d in drives]), np.concatenate(poses_by_drive))
    return {"translation_percent": km["translation_percent"], "rotation_deg_per_m": km["rotation_deg_per_m"],
            "num_segments": km["num_segments"], "mean_step_translation_m": rel["mean_translation_m"],
            "mean_step_rotation_deg": rel["mean_rotation_deg"]}


# ---------------------------------------------------------------------------------------- speed
def graph_ms(path, drives, threads: int, steps: int) -> dict:
    """Median / p90 graph time (ms) of ``steps`` stream steps on the drives' sweeps."""
    from radar_odom.onnx_model import OnnxModel

    om = OnnxModel(path, threads=threads)
    images = np.concatenate([d.images for d in drives]).astype(np.float32)
    state = np.zeros(om.info.state_shape, dtype=np.float32)
    times = []
    for i in range(steps + 10):
        t = time.perf_counter()
        state = om.run({"cart": images[i % len(images)][None], "prev_state": state})["state"]
        if i >= 10:
            times.append(time.perf_counter() - t)
    ms = np.array(times) * 1e3
    return {"median": float(np.median(ms)), "p90": float(np.percentile(ms, 90))}


def polar_to_cartesian_ms(profile, reps: int = 30) -> float:
    """Median time of the runtime's polar→Cartesian of one simulated sweep at ``profile``."""
    from radar_odom.polar import polar_to_cartesian
    from radar_odom.sim import simulate_drive

    scan = next(iter(simulate_drive(5999, 1))).scan
    polar_to_cartesian(scan, profile.resolution_m, profile.width_px, near_range_m=profile.near_range_m)
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        polar_to_cartesian(scan, profile.resolution_m, profile.width_px, near_range_m=profile.near_range_m)
        times.append(time.perf_counter() - t)
    return float(np.median(times) * 1e3)


def export_for_speed(model, setting, path: Path):
    from radar_odom_export.onnx_export import export_fast, export_model

    if path.is_file():
        return path
    if setting is None:
        export_model(model, path, verify=False)
    else:
        export_fast(model, path, setting, verify=False)
    return path


# ---------------------------------------------------------------------------------------- output
def markdown(results: dict, header: str) -> str:
    lines = [header, "",
             "| profile | search | yaws at full res | KITTI t % | KITTI r deg/m | mean step Δt m | mean step Δyaw ° "
             "| graph ms (median / p90) | step ms (p→C + graph) |", "|---|---|---|---|---|---|---|---|---|"]
    for r in results.values():
        a = r.get("accuracy") or {}
        g = r.get("graph_ms") or {}
        lines.append(
            f"| {r['profile']} | {r['search']} | {r['band']} | {a.get('translation_percent', math.nan):.2f} "
            f"| {a.get('rotation_deg_per_m', math.nan):.4f} | {a.get('mean_step_translation_m', math.nan):.3f} "
            f"| {a.get('mean_step_rotation_deg', math.nan):.3f} "
            f"| {g.get('median', math.nan):.1f} / {g.get('p90', math.nan):.1f} "
            f"| {r.get('step_ms', math.nan):.1f} |"
        )
    return "\n".join(lines) + "\n"


def plot(results: dict, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import textwrap

    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8))
    colours = {"cart-0.8": "tab:blue", "cart-0.4": "tab:orange", "cart-0.2": "tab:green"}
    paper_ms = {"cart-0.8": 11.3, "cart-0.4": 16.9, "cart-0.2": 48.5}  # the paper's Titan Xp step
    for r in results.values():
        if not r.get("accuracy") or "step_ms" not in r:
            continue
        c = colours.get(r["profile"], "tab:grey")
        marker = "s" if r["search"] == "exhaustive" else "o"
        for ax, key in zip(axes, ("translation_percent", "rotation_deg_per_m")):
            ax.scatter(r["step_ms"], r["accuracy"][key], color=c, marker=marker, s=40)
            ax.annotate(
                r["search"],
                (r["step_ms"], r["accuracy"][key]),
                fontsize=6,
                alpha=0.8,
                xytext=(3, 3),
                textcoords="offset points",
            )
    for ax, lab in zip(axes, ("KITTI translational error (%)", "KITTI rotational error (deg/m)")):
        for name, ms in paper_ms.items():
            ax.axvline(ms, color=colours[name], ls="--", lw=0.8, alpha=0.6)
        ax.set_xlabel("step: polar→Cartesian + graph (ms, median; dashed: paper's GPU step)")
        ax.set_ylabel(lab)
        ax.set_xscale("log")
        ax.grid(alpha=0.3)
    handles = [plt.Line2D([], [], color=c, marker="o", ls="", label=p) for p, c in colours.items()]
    handles.append(plt.Line2D([], [], color="k", marker="s", ls="", label="exhaustive (square)"))
    axes[0].legend(handles=handles, fontsize=8)
    fig.suptitle("\n".join(textwrap.wrap(title, 150)), fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ---------------------------------------------------------------------------------------- main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--profiles", nargs="+", default=list(DEFAULT_SETTINGS))
    ap.add_argument(
        "--settings",
        nargs="*",
        default=None,
        help="fast settings for every profile (default: three per profile, see DEFAULT_SETTINGS)",
    )
    ap.add_argument("--seeds", default="5000", help="held-out world seeds, >= 5000 (default: %(default)s)")
    ap.add_argument("--scenarios", default="urban,heavy_traffic,open,highway")
    ap.add_argument("--frames", type=int, default=240, help="sweeps per drive (default: %(default)s = 60 s)")
    ap.add_argument("--lengths", default="100,200", help="KITTI segment lengths, m (default: %(default)s)")
    ap.add_argument("--masks", choices=("checkpoint", "raw", "labels"), default="labels")
    ap.add_argument("--checkpoint", nargs="*", default=[], metavar="PROFILE=PATH")
    ap.add_argument("--threads", type=int, default=2, help="onnxruntime and torch threads")
    ap.add_argument("--steps", type=int, default=100, help="timed graph steps per search")
    ap.add_argument("--no-speed", action="store_true", help="accuracy only")
    ap.add_argument("-o", "--output", default="bench-speed-accuracy")
    args = ap.parse_args(argv)

    import torch

    from radar_odom.profiles import get_profile
    from radar_odom_export.checkpoint import load_checkpoint
    from radar_odom_export.data import build_drives, check_seed_policy, parse_seeds, sim_specs
    from radar_odom_export.fast_search import FastStreamStep
    from radar_odom_export.model import MaskedCorrelator

    torch.set_num_threads(args.threads)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    seeds = parse_seeds(args.seeds)
    check_seed_policy(seeds, "eval")
    lengths = tuple(float(v) for v in args.lengths.split(","))
    checkpoints = dict(c.split("=", 1) for c in args.checkpoint)
    json_path = out / "speed_accuracy.json"
    results = json.loads(json_path.read_text())["results"] if json_path.is_file() else {}
    specs = sim_specs(seeds, [s for s in args.scenarios.split(",") if s], args.frames)
    for name in args.profiles:
        profile = get_profile(name)
        drives = build_drives(profile, specs, with_labels=args.masks == "labels")
        if args.masks == "checkpoint":
            if name not in checkpoints:
                raise SystemExit(f"--masks checkpoint needs --checkpoint {name}=PATH")
            model, _ = load_checkpoint(checkpoints[name])
            speed_model = model
        else:
            model = MaskedCorrelator(profile, masking="external" if args.masks == "labels" else "raw").eval()
            torch.manual_seed(0)
            speed_model = MaskedCorrelator(profile, masking="learned").eval()
        p2c = None if args.no_speed else polar_to_cartesian_ms(profile)
        searches = [None] + [parse_setting(s) for s in (args.settings or DEFAULT_SETTINGS.get(name, []))]
        for setting in searches:
            label = "exhaustive" if setting is None else setting.label()
            key = f"{name}/{label}/{args.masks}/{args.seeds}/{args.frames}"
            r = results.setdefault(key, {"profile": name, "search": label, "masks": args.masks})
            r["band"] = profile.num_rotations if setting is None else setting.band_size(profile)
            if "accuracy" not in r:
                step = model.stream_step if setting is None else FastStreamStep(model, setting).eval()
                t = time.perf_counter()
                poses = [stream_poses(step, model, d, args.masks == "labels") for d in drives]
                r["accuracy"] = accuracy(poses, drives, lengths)
                r["torch_s"] = time.perf_counter() - t
            if not args.no_speed and "graph_ms" not in r:
                onnx_path = export_for_speed(speed_model, setting, out / "models" / f"{name}-{label}.onnx")
                r["graph_ms"] = graph_ms(onnx_path, drives, args.threads, args.steps)
                r["step_ms"] = r["graph_ms"]["median"] + p2c
            print(
                f"{name} {label}: {r['accuracy']['translation_percent']:.2f} %, "
                f"{r['accuracy']['rotation_deg_per_m']:.4f} deg/m"
                + (f", step {r['step_ms']:.1f} ms" if "step_ms" in r else ""),
                flush=True,
            )
            json_path.write_text(json.dumps({"args": vars(args), "results": results}, indent=2))
    import os

    header = (
        f"Drives: seeds {args.seeds} × scenarios {args.scenarios}, {args.frames} sweeps each; masks: {args.masks}; "
        f"KITTI segments {args.lengths} m every 4 frames; {args.threads} threads; "
        f"load average at the end {os.getloadavg()[0]:.2f}."
    )
    (out / "speed_accuracy.md").write_text(markdown(results, header))
    plot(results, out / "speed_accuracy.png", header)
    print(f"wrote {out / 'speed_accuracy.md'}, {out / 'speed_accuracy.png'}, {json_path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Where the straight-road yaw bias comes from (issue 41): the graph's own yaw on straight simulated roads,
split by what each variant of the sweeps keeps or takes away.

    python benchmarks/yaw_bias.py                                     # cart-0.4, 4 fresh seeds × 28 sweeps; ≈ 3 min
    python benchmarks/yaw_bias.py --models cart-0.4,cart-0.8 --write /tmp/yawfix   # export the fix (below)
    python benchmarks/yaw_bias.py --models cart-0.4 --fix average --write /tmp/mirror   # the masks averaged
    python benchmarks/yaw_bias.py --models cart-0.4,/tmp/prev/cart-0.4.onnx --seeds 20000,20001

Every row is the mean (estimated − true) yaw per sweep, ° ± its standard error over the pairs, of the
graph alone (consecutive sweeps through the ONNX stream step, no motion prior, no de-skew), over
straight roads at 10 m/s (`scorecard.bend_scenario(0.0, --scenario)`, urban by default), pairs 5… of
each drive (the first 4 are the speed ramp). Seeds are fresh
(>= 10000: lower ones trained, calibrated or tuned something).

``shift``: one sweep (frozen, below) drawn again in a frame moved by a pure translation
(`SweepMotion(frame_pose=(dx, 0, 0))`) and matched against itself: the same content, no rotation.
A yaw read here is the implementation's (rotation, coarse pick, read-out, polar → Cartesian).

``world``: the drives themselves, varied one way at a time:

* *moving*: as simulated (every azimuth drawn from the ego pose at its own time: motion distortion);
* *moving, de-skewed*: the same through `RadarOdometer(deskew=True, motion_prior=False)`;
* *frozen*: every azimuth drawn from the pose at the sweep's mid time (no distortion, same noise);
* *still*: frozen at one instant for the whole drive (no motion at all, fresh noise every sweep);
* *mirrored world*: the world, the traffic and the ego path reflected (y → −y, so the ego drives on
  the right and the nearer kerb is on its right), the radar unchanged (it still scans the same way);
* *mirrored sweeps*: the simulated sweeps mirrored (azimuths negated), the estimate's yaw negated
  back: the world *and* the radar reflected, the method not.

With frozen sweeps, a bias ``b = W + S + M`` (W: the world's left/right asymmetry, S: the radar's
handedness, M: the method's) reads ``−W + S + M`` in the mirrored world and ``W + S − M`` from
mirrored sweeps; the script prints the three parts solved from the three rows.

``stages`` (torch, the shipped checkpoint of the first ``--models`` name): which stage of the graph
reads the bias, on the same straight drives (moving and frozen), each in torch's fast step: the
shipped profile (cubic polar rotation, its high-pass), the same with the bilinear polar rotation,
without the high-pass, with the mask ≡ 1 (raw), and, taking the graph's rotation and read-out out
altogether, the shipped masked features turned by exact (Fourier) rotations every quarter yaw step
and read at the parabola through the best translation score of each (`yaw_kernels.py`'s tools).

``bend``: what a fix must not cost: the yaw error and yaw slope on a steady ``--bend`` (°/sweep).

``--write DIR``: the fix, built: the shipped checkpoints (``--models``' names) with a left/right
symmetric masker (``--fix symmetric``: every kernel averaged with its mirror image) or with their masks
averaged over the mirror (``--fix average``: `GridProfile.mask_mirror_average`, the weights as shipped;
`radar_odom_export.symmetry`), written as DIR/NAME.pt and exported as DIR/NAME.onnx with the shipped
file's search and its settings (the calibration is the shipped checkpoint's). ``--export DIR`` exports
DIR/NAME.pt again the same way, e.g. after ``radar-odom calibrate DIR/NAME.pt``. Then measure them with
``--models DIR/NAME.onnx`` or the scorecard's ``--candidate-dir DIR``. Needs the export extra (torch, onnx).
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

SKIP_PAIRS = 4  # the constant-speed drive's ramp
STILL_AT_S = 3.0  # drive time at which a "still" drive stands (past the ramp)
SHIFTS_M = (2.5, -2.5, 2.2)  # one step at 10 m/s and 4 Hz, backwards, and off the pixel grid


def reflect_y(points_m) -> np.ndarray:
    """float64[..., 2] points (x, y) in metres reflected across the world's x axis (y → −y)."""
    out = np.array(points_m, dtype=np.float64, copy=True)
    out[..., 1] *= -1.0
    return out


def simulator_class(frozen: bool = False, mirror: bool = False, still_at_s: float | None = None):
    """A `Simulator` subclass drawing sweeps ``frozen`` (every azimuth at the sweep's mid time), in the
    ``mirror``-ed world (world, traffic and ego path reflected y → −y; the radar's scan direction kept)
    or ``still`` at drive time ``still_at_s`` (frozen there for every sweep; fresh noise each sweep)."""
    from radar_odom.sim.sensor import Points, Segments
    from radar_odom.sim.simulator import Simulator

    class Variant(Simulator):
        def drive_time_s(self, timestamps_us):
            t = np.asarray(super().drive_time_s(timestamps_us), dtype=np.float64)
            if still_at_s is not None:
                return np.full_like(t, still_at_s)
            return np.full_like(t, t.mean()) if frozen and t.ndim else t

        def pose_mid(self, k):
            pose = super().pose_mid(k)
            if not mirror:
                return pose
            flip = np.diag([1.0, -1.0, 1.0])  # a pose reflected: y and the heading change sign
            return flip @ pose @ flip

        def scene(self, k):
            orig, yaw, segments, points = super().scene(k)
            if not mirror:
                return orig, yaw, segments, points
            # every position reflected y → −y, headings negated
            return (reflect_y(orig), -np.asarray(yaw),
                    [Segments(reflect_y(g.a), reflect_y(g.b), g.refl_db, g.trans_db, moving=g.moving)
                     for g in segments],
                    [Points(reflect_y(q.xy), q.refl_db, moving=q.moving) for q in points])

    return Variant


def mirrored_scan(scan):
    """The sweep reflected left/right: azimuth φ → −φ (rows re-sorted so azimuths increase), the
    timestamps left in place (so the mirrored sweep is scanned the other way round)."""
    from radar_odom.scan import RadarScan

    az = np.mod(-scan.azimuths_rad.astype(np.float64), 2 * math.pi)
    order = np.argsort(az, kind="stable")
    return RadarScan.from_arrays(scan.timestamps_us, az[order].astype(np.float32),
                                 np.ascontiguousarray(scan.power[order]), valid=np.ascontiguousarray(scan.valid[order]),
                                 range_resolution_m=scan.range_resolution_m)


def stream_yaws_rad(model, inputs) -> np.ndarray:
    """float64[N − 1]: the graph's yaw (rad) of each consecutive pair of graph inputs (stream form)."""
    names = model.info.inputs
    state = model.run({names[0]: inputs[0], names[1]: np.zeros(model.info.state_shape, np.float32)})["state"]
    out = []
    for x in inputs[1:]:
        res = model.run({names[0]: x, names[1]: state})
        state = res["state"]
        out.append(float(np.asarray(res["pose"]).reshape(3)[2]))
    return np.array(out)


def pair_yaw_rad(model, ref, cur) -> float:
    """The graph's yaw (rad) of ``cur`` matched against ``ref`` (graph inputs)."""
    return float(stream_yaws_rad(model, [ref, cur])[0])


SCENARIO = ["urban"]  # the simulator preset every drive uses (--scenario)


def drive(seed: int, frames: int, rate_deg: float = 0.0, **variant):
    """(scans, true yaw float64[frames − 1] rad) of a drive at 10 m/s on the ``--scenario`` preset,
    straight or bending ``rate_deg`` per sweep."""
    from scorecard import bend_scenario

    sim = simulator_class(**variant)(seed, frames, bend_scenario(rate_deg, SCENARIO[0]))
    fr = list(sim)
    truth = np.array([f.pose_rel[2] for f in fr[1:]])
    if variant.get("still_at_s") is not None:
        truth = np.zeros_like(truth)  # pose_mid follows the drive; a still drive does not move
    return [f.scan for f in fr], truth


def mean_se_deg(values_rad) -> tuple[float, float]:
    v = np.degrees(np.asarray(values_rad, dtype=np.float64))
    return float(v.mean()), float(v.std(ddof=1) / math.sqrt(len(v)))


def part_shift(models: dict, seeds, frames: int) -> None:
    from radar_odom.odometry.sweep_input import SweepMotion, graph_input

    yaws = {(n, s): [] for n in models for s in SHIFTS_M}
    for seed in seeds:
        scans, _ = drive(seed, frames, frozen=True)
        for scan in scans[SKIP_PAIRS + 1:]:
            for name, m in models.items():
                ref = graph_input(scan, m.info)
                for s in SHIFTS_M:
                    cur = graph_input(scan, m.info, SweepMotion(frame_pose=(s, 0.0, 0.0)))
                    yaws[name, s].append(pair_yaw_rad(m, ref, cur))
    print("\n| model | pure forward shift of one sweep, m | yaw read ° (± s.e.) | pairs |\n|---|---:|---:|---:|")
    for (name, s), v in yaws.items():
        mean, se = mean_se_deg(v)
        print(f"| {name} | {s:+.1f} | {mean:+.4f} ± {se:.4f} | {len(v)} |", flush=True)


WORLD_ROWS = (  # label, simulator variant, sweeps mirrored, de-skewed by the runtime
    ("moving", {}, False, False),
    ("moving, de-skewed", {}, False, True),
    ("moving, mirrored world", {"mirror": True}, False, False),
    ("moving, mirrored sweeps", {}, True, False),
    ("frozen", {"frozen": True}, False, False),
    ("frozen, mirrored world", {"frozen": True, "mirror": True}, False, False),
    ("frozen, mirrored sweeps", {"frozen": True}, True, False),
    ("still", {"still_at_s": STILL_AT_S}, False, False),
)


def deskewed_yaws_rad(model, scans) -> np.ndarray:
    """float64[N − 1]: `RadarOdometer`'s yaw (rad) per pair with de-skew on and the motion prior off
    (the graph's own matches of de-skewed sweeps)."""
    from radar_odom import RadarOdometer

    odo = RadarOdometer(model, deskew=True, motion_prior=False)
    est = [odo.step(s) for s in scans]
    return np.array([e.pose[2] for e in est[1:]])


def part_world(models: dict, seeds, frames: int) -> None:
    from radar_odom.odometry.sweep_input import graph_input

    errs = {}
    for label, variant, mirrored, deskew in WORLD_ROWS:
        for seed in seeds:
            scans, truth = drive(seed, frames, **variant)
            if mirrored:
                scans = [mirrored_scan(s) for s in scans]
            for name, m in models.items():
                est = (deskewed_yaws_rad(m, scans) if deskew else
                       stream_yaws_rad(m, [graph_input(s, m.info) for s in scans]))
                est = -est if mirrored else est
                errs.setdefault((name, label), []).extend((est - truth)[SKIP_PAIRS:].tolist())
    print("\n| model | sweeps | yaw error ° / sweep (± s.e.) | pairs |\n|---|---|---:|---:|")
    for (name, label), v in errs.items():
        mean, se = mean_se_deg(v)
        print(f"| {name} | {label} | {mean:+.4f} ± {se:.4f} | {len(v)} |", flush=True)
    print("\nFrozen sweeps split (b = W + S + M; mirrored world −W + S + M; mirrored sweeps W + S − M):")
    for name in models:
        b, mw, ms = (mean_se_deg(errs[name, k])[0]
                     for k in ("frozen", "frozen, mirrored world", "frozen, mirrored sweeps"))
        world, method = (b - mw) / 2, (b - ms) / 2
        print(f"  {name}: world W {world:+.4f}, radar S {b - world - method:+.4f}, method M {method:+.4f} °/sweep; "
              f"motion distortion (moving − frozen) {mean_se_deg(errs[name, 'moving'])[0] - b:+.4f}")


FIXES = ("symmetric", "average")  # --fix: the kernels averaged with their mirror images, or the masks


def write_fixed(names, out_dir: Path, fix: str = "symmetric") -> None:
    """DIR/NAME.pt (the shipped checkpoint, its masker made left/right symmetric: ``fix`` "symmetric",
    `symmetry.mirror_symmetric_checkpoint`; or its masks averaged over the mirror: "average",
    `symmetry.mirror_averaged_checkpoint`) and DIR/NAME.onnx (`export_like_shipped`)."""
    from radar_odom_export.checkpoint import read_checkpoint_dict, resolve_checkpoint, write_checkpoint_dict
    from radar_odom_export.symmetry import mirror_averaged_checkpoint, mirror_symmetric_checkpoint

    make = mirror_symmetric_checkpoint if fix == "symmetric" else mirror_averaged_checkpoint
    out_dir.mkdir(parents=True, exist_ok=True)
    for name in names:
        write_checkpoint_dict(out_dir / f"{name}.pt", make(read_checkpoint_dict(resolve_checkpoint(name))))
    export_like_shipped(names, out_dir)


def export_like_shipped(names, out_dir: Path) -> None:
    """DIR/NAME.pt exported to DIR/NAME.onnx as the shipped NAME.onnx is: its search with the settings its
    metadata records (`model_zoo.shipped_export`), so the candidate keeps the shipped search even where
    `fast_search.DEFAULT_SETTINGS` (what ``radar-odom export DIR/NAME.pt --search fast`` takes) changes later."""
    from radar_odom.model_zoo import shipped_export
    from radar_odom_export.onnx_export import export_checkpoint

    for name in names:
        how = shipped_export(name)
        report = export_checkpoint(out_dir / f"{name}.pt", out_dir / f"{name}.onnx", form=how["form"],
                                   search=how["search"], search_settings=how["settings"])
        print(report.summary(), flush=True)


def part_stages(name: str, seeds, frames: int) -> None:
    import torch
    from yaw_kernels import best_scores, parabola_peak, rotate_fft

    from radar_odom.odometry.sweep_input import graph_input
    from radar_odom.profiles import GridProfile
    from radar_odom_export.checkpoint import read_checkpoint_dict, resolve_checkpoint
    from radar_odom_export.fast_search import FastStreamStep
    from radar_odom_export.model import MaskedCorrelator
    from radar_odom_export.symmetry import symmetrise_left_right_

    ckpt = read_checkpoint_dict(resolve_checkpoint(name))
    base = GridProfile.from_dict(ckpt["profile"])

    def step(masking="learned", symmetric=False, **changes):
        model = MaskedCorrelator(base.with_(**changes) if changes else base, masking=masking)
        if masking == "learned":
            model.load_state_dict(ckpt["state_dict"], strict=True)
            if symmetric:
                symmetrise_left_right_(model.masker)
        return FastStreamStep(model.eval()).eval()

    steps = {f"graph: {base.rotation_kernel} rotation, high-pass {base.feature_highpass_px:g} px (shipped)": step(),
             "graph: bilinear rotation": step(rotation_kernel="bilinear"),
             "graph: no high-pass": step(feature_highpass_px=0.0),
             "graph: mask ≡ 1 (raw)": step("raw"),
             "graph: mirror-symmetric masker (the fix)": step(symmetric=True)}
    exact = "shipped features, exact rotation, parabola (no graph rotation or read-out)"
    info = type("Info", (), {"profile": base, "polar_input": None})()
    quarter, shifts, n = base.rotation_step_rad / 4, range(-6, 7), base.translation_cells
    zero = torch.zeros(1, 2, base.width_px, base.width_px // 2 + 1)
    errs = {}
    for frozen in (False, True):
        for seed in seeds:
            scans, truth = drive(seed, frames, frozen=frozen)
            x = [torch.from_numpy(graph_input(s, info)) for s in scans]
            with torch.no_grad():
                for label, st in steps.items():
                    _, _, state = st(x[0], zero)
                    for k in range(1, len(x)):
                        pose, _, state = st(x[k], state)
                        if k - 1 >= SKIP_PAIRS:
                            errs.setdefault((frozen, label), []).append(float(pose[0, 2]) - truth[k - 1])
                feats = [steps[next(iter(steps))].model.sweep_features(xi)[0].numpy() for xi in x]
            for k in range(SKIP_PAIRS + 1, len(x)):
                scores = best_scores(feats[k - 1], [rotate_fft(feats[k], s * quarter) for s in shifts], n)
                est = (parabola_peak(scores) - len(shifts) // 2) * quarter
                errs.setdefault((frozen, exact), []).append(est - truth[k - 1])
    print(f"\n| {name}: sweeps | stage | yaw error ° / sweep (± s.e.) | pairs |\n|---|---|---:|---:|")
    for (frozen, label), v in errs.items():
        mean, se = mean_se_deg(v)
        print(f"| {'frozen' if frozen else 'moving'} | {label} | {mean:+.4f} ± {se:.4f} | {len(v)} |", flush=True)


def part_bend(models: dict, seeds, frames: int, rate_deg: float) -> None:
    """A fix for the bias must not cost the bends: the yaw error and the yaw slope (Σ est·true / Σ true²)
    on a steady bend of ``rate_deg`` per sweep, as simulated (moving)."""
    from radar_odom.odometry.sweep_input import graph_input

    rows = {name: ([], []) for name in models}
    for seed in seeds:
        scans, truth = drive(seed, frames, rate_deg)
        for name, m in models.items():
            est = stream_yaws_rad(m, [graph_input(s, m.info) for s in scans])
            rows[name][0].extend(est[SKIP_PAIRS:].tolist())
            rows[name][1].extend(truth[SKIP_PAIRS:].tolist())
    print(f"\n| model | bend {rate_deg} °/sweep: yaw error ° (± s.e.) | yaw slope | pairs |\n|---|---:|---:|---:|")
    for name, (est, true) in rows.items():
        est, true = np.array(est), np.array(true)
        mean, se = mean_se_deg(est - true)
        print(f"| {name} | {mean:+.4f} ± {se:.4f} | {np.sum(est * true) / np.sum(true * true):.3f} | {len(est)} |",
              flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--models", default="cart-0.4",
                    help="shipped names or .onnx paths, comma-separated (default: %(default)s)")
    ap.add_argument("--seeds", default="20000,20001,20002,20003", help="fresh seeds >= 10000 (default: %(default)s)")
    ap.add_argument("--frames", type=int, default=28, help="sweeps per drive (default: %(default)s)")
    ap.add_argument("--parts", default="shift,world,bend",
                    help="shift, world, bend, stages (torch) (default: %(default)s)")
    ap.add_argument("--scenario", default="urban", help="simulator preset of the drives (default: %(default)s)")
    ap.add_argument("--bend", type=float, default=0.5, help="the bend part's rate, ° per sweep (default: %(default)s)")
    ap.add_argument("--threads", type=int, default=1, help="onnxruntime threads (default: %(default)s)")
    ap.add_argument("--write", type=Path, default=None, metavar="DIR",
                    help="write the fix (--fix) of the named shipped models to DIR and exit")
    ap.add_argument("--fix", choices=FIXES, default="symmetric",
                    help="--write's fix: symmetric: every masker kernel averaged with its mirror image; average: the "
                         "masks averaged over the mirror (GridProfile.mask_mirror_average) (default: %(default)s)")
    ap.add_argument("--export", type=Path, default=None, metavar="DIR",
                    help="export DIR/NAME.pt (e.g. after `radar-odom calibrate`) to DIR/NAME.onnx as the shipped "
                         "NAME.onnx is (its search settings) and exit")
    args = ap.parse_args(argv)
    if args.write is not None:
        write_fixed(args.models.split(","), args.write, args.fix)
        return 0
    if args.export is not None:
        export_like_shipped(args.models.split(","), args.export)
        return 0
    seeds = [int(s) for s in args.seeds.split(",")]
    SCENARIO[0] = args.scenario
    if min(seeds) < 10000:
        ap.error("seeds below 10000 trained, calibrated or tuned something: use fresh ones")
    if args.frames < SKIP_PAIRS + 3:
        ap.error(f"--frames must be at least {SKIP_PAIRS + 3}: the first {SKIP_PAIRS} pairs are the ramp")

    from radar_odom.model_zoo import resolve_model
    from radar_odom.onnx_model import OnnxModel

    models = {m: OnnxModel(resolve_model(m), threads=args.threads) for m in args.models.split(",")}
    print(f"seeds {', '.join(map(str, seeds))}; {args.frames} sweeps per drive; {args.scenario} road at 10 m/s; "
          f"graph alone; pairs {SKIP_PAIRS + 1}… of each drive", flush=True)
    t0 = time.perf_counter()
    parts = args.parts.split(",")
    if "shift" in parts:
        part_shift(models, seeds, args.frames)
    if "world" in parts:
        part_world(models, seeds, args.frames)
    if "stages" in parts:
        part_stages(args.models.split(",")[0], seeds, args.frames)
    if "bend" in parts:
        part_bend(models, seeds, args.frames, args.bend)
    print(f"\n{time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""`radar-odom adapt` measured: on real radar without a reference, scored where one exists.

Parts (``--parts``, default all three):

* ``radiate``: adapt the shipped model on the shared RADIATE drive's first 200 sweeps, radar only
  (``radar-odom adapt DRIVE --sweeps :200``, defaults), then score shipped and adapted on its last
  80 sweeps (105 m, never seen) against the GNSS/INS reference (`real_drive.py --stretch 200:`).
* ``fog``: adapt on ``radiate-fog_6_0`` (18 sweeps, no usable reference): its held-out
  self-consistency figures only.
* ``skips``: why pairs several sweeps apart are labelled by composition: the shipped graph's step
  scale against the reference for pairs k → k + s, s = 1, 2, 3, over the whole drive.
* ``sim``: the simulated scenarios before and after (seeds 5000–5001, `eval_onnx.py` with the
  runtime's motion prior): the adapted model is for the real radar; this says what it costs on
  the simulated ones.

    python benchmarks/adapt.py                                   # ≈ 45 min on 2 cores
    python benchmarks/adapt.py --parts radiate sim --model m.onnx  # score a model adapted before

The adapted files go to ``--out`` (default ``./adapt-bench``).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REAL = HERE.parents[1] / "shared" / "data" / "real"
DRIVE = REAL / "radiate-2019-02-12-edinburgh"
FOG = REAL / "radiate-fog_6_0"


def run_adapt(recording: Path, out: Path, extra: list[str]) -> Path:
    cmd = [sys.executable, "-m", "radar_odom", "adapt", str(recording), "-o", str(out), "--force", *extra]
    print("$ radar-odom adapt " + " ".join(str(c) for c in cmd[4:]), flush=True)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True)
    print(f"(adapt took {(time.perf_counter() - t0) / 60:.1f} min)", flush=True)
    return out


def skip_scales(model_name: str, max_skip: int = 3) -> None:
    """Step scale (estimated · true / true², over pairs moving ≥ 0.5 m per sweep apart), direction
    and yaw slope of the graph alone for pairs k → k + s of the shared drive, against its reference."""
    import numpy as np
    import real_drive

    from radar_odom import pretrained
    from radar_odom.evaluation.reference import gnss_reference
    from radar_odom.io import read_sequence
    from radar_odom.se2 import invert, to_xyyaw
    from radar_odom_export.adapt import stream_matcher

    seq = read_sequence(DRIVE)
    scans = [f.scan for f in seq]
    ref_poses, _, _ = real_drive.run_model(pretrained(model_name), scans, deskew=False)
    gt, _, _ = gnss_reference(seq.reference, seq.timestamps_us, ref_poses)
    match = stream_matcher(pretrained(model_name), scans, threads=2)
    print(f"{model_name}, graph alone, pairs k → k + s of the shared drive against its GNSS/INS reference:")
    for s in range(1, max_skip + 1):
        k = np.arange(len(scans) - s)
        est = np.array([match(i, i + s) for i in k])
        true = to_xyyaw(invert(gt[k]) @ gt[k + s])
        ok = np.hypot(true[:, 0], true[:, 1]) > 0.5 * s
        scale = float((est[ok, :2] * true[ok, :2]).sum() / (true[ok, :2] ** 2).sum())
        slope = float((est[ok, 2] * true[ok, 2]).sum() / (true[ok, 2] ** 2).sum())
        print(f"  s = {s}: {int(ok.sum())} pairs, mean true step {np.hypot(true[ok, 0], true[ok, 1]).mean():.2f} m, "
              f"step scale {scale:.3f}, yaw slope {slope:.3f}", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--parts", nargs="+", choices=("radiate", "fog", "skips", "sim"),
                    default=["radiate", "fog", "skips", "sim"])
    ap.add_argument("--model", type=Path, default=None,
                    help="an adapted model to score (radiate, sim) instead of adapting one")
    ap.add_argument("--base", default="cart-0.4", help="the shipped model adapted from (default: %(default)s)")
    ap.add_argument("--out", type=Path, default=Path("adapt-bench"), help="folder for the adapted models")
    ap.add_argument("--sim-frames", type=int, default=240, help="sweeps per simulated drive (default: %(default)s)")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    sys.path.insert(0, str(HERE))
    model = args.model
    if "radiate" in args.parts:
        if not (DRIVE / "GPS_IMU_Twist").is_dir():
            print(f"{DRIVE}: not there (the shared real data); radiate part skipped", file=sys.stderr)
        else:
            if model is None:
                model = run_adapt(DRIVE, args.out / "radiate-200.onnx", ["--sweeps", ":200", "--from", args.base])
            import real_drive

            real_drive.main(["--models", args.base, str(model), "--no-classical", "--no-deskew", "--no-kiss",
                             "--stretch", "200:"])
    if "fog" in args.parts:
        if not FOG.is_dir():
            print(f"{FOG}: not there; fog part skipped", file=sys.stderr)
        else:
            fog = run_adapt(FOG, args.out / "fog.onnx", ["--from", args.base])
            report = json.loads(fog.with_suffix(".adapt.json").read_text())
            print(json.dumps(report["recordings"][0]["self_consistency"], indent=1))
    if "skips" in args.parts and (DRIVE / "GPS_IMU_Twist").is_dir():
        skip_scales(args.base)
    if "sim" in args.parts:
        if model is None:
            print("sim part: no adapted model (give --model, or run the radiate part)", file=sys.stderr)
            return 2
        import eval_onnx

        from radar_odom import pretrained

        eval_onnx.main([pretrained(args.base), str(model), "--seeds", "5000-5001", "--frames", str(args.sim_frames),
                        "--motion-prior", "-o", str(args.out / "sim.json")])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Where does the time of one odometry step go? Stage and operator timings of one model.

    python examples/latency_profile.py                    # the shipped cart-0.4 model
    python examples/latency_profile.py my_model.onnx --steps 300

The same measurements as ``radar-odom profile`` (which covers every resolution, adds the
numpy-FFT reference and a 1000-step memory check, and writes JSON and markdown), for one model.
"""
import argparse

import radar_odom
from radar_odom.latency.stats import format_machine, machine_info
from radar_odom.latency.sweeps import simulated_pngs
from radar_odom.latency.timing import profile_model

ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
ap.add_argument("model", nargs="?", default="cart-0.4", help="shipped model name or .onnx path")
ap.add_argument("--steps", type=int, default=200)
ap.add_argument("--threads", type=int, default=2)
args = ap.parse_args()

path = args.model if args.model.endswith(".onnx") else radar_odom.pretrained(args.model)
print(format_machine(machine_info(args.threads)))
result = profile_model(path, simulated_pngs(16), steps=args.steps, threads=args.threads, reference_steps=10)

print(f"\n{'stage':20s} {'median':>8s} {'p90':>8s} {'p99':>8s}   (ms over {args.steps} steps)")
for stage, s in result.stages.items():
    print(f"{stage:20s} {s['median']:8.2f} {s['p90']:8.2f} {s['p99']:8.2f}")
print("\nmost expensive operator classes inside the graph (ms per step, median):")
for op, s in list(result.operators.items())[:6]:
    print(f"  {op:16s} {s['median']:6.2f}  ({100 * s['share']:.0f} %)")
for kind, ref in result.reference.items():
    ratio = result.stages["graph"]["median"] / ref["time"]["median"]
    print(f"graph / numpy-FFT reference ({kind.replace('_', ' ')}): {ratio:.2f}")
print(f"peak RSS {result.peak_rss_mb:.0f} MiB")

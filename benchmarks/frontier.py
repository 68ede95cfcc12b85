"""The speed–accuracy frontier of cart-0.4 (issue 52 item 1): every candidate graph, timed and scored.

    python benchmarks/frontier.py -o /work/frontier-out                 # fresh seeds, printed
    python benchmarks/frontier.py -o /work/frontier-out --seeds 123456  # repeat (or resume) a run
    python benchmarks/frontier.py -o OUT --only today,int8-ff           # some candidates only

Candidates (`CANDIDATES`; each built once into ``OUT/candidates/NAME.onnx`` and reused, so a run
resumes): today's shipped file; the static QDQ int8 masker (`radar_odom_export.quantize`,
calibrated on simulated validation drives and the shared RADIATE drive without its held-out last
80 sweeps) with the first and last Conv float32, and with every Conv int8; the shipped checkpoint
re-exported with fewer yaw candidates in the coarse stage (``c4s4b2``, ``c4s6b2``: every 4th / 6th
yaw instead of every 3rd; the re-export carries the checkpoint's calibration, as the shipped file
does: checked, the metadata must equal the shipped file's but for the search); int8 on a fewer-yaw
export; and the masker on a grid 4x coarser than the sweep's (``mask-md4``: the shipped checkpoint with its
profile's ``mask_downsample`` 4 instead of 2, the weights not trained for it). `NOT_BUILT` lists the candidates
the issue names that this script does not build, and why.

For every candidate, one row:

* step time: every candidate's graph stepped interleaved in one process (`compare_graphs.
  interleaved_times`, 2 threads, ``--steps`` steps each, same sweep, alternating order); the median
  and the p10 as ratios to today's file, with a bootstrap spread of the median ratio;
* accuracy: the scorecard's rows (`benchmarks/scorecard.py`'s functions: fresh simulated drives of
  every scenario, straight roads and bends, the shared RADIATE drive whole and its held-out stretch,
  the Oxford pair, fog), on seeds drawn at run time (printed; the same drives for every candidate),
  each candidate as `RadarOdometer` runs it; every row is compared with today's file by the
  scorecard's verdict (worse beyond the two spreads combined), and the count of worse rows is shown.

Writes ``OUT/frontier.json`` (everything), ``OUT/frontier.md`` (the table) and ``OUT/frontier.png``
(step ratio against the simulated KITTI translation error, each candidate labelled, with the line of
half the paper's GPU step as a ratio to today's step: 0.5 × 16.9 ms / ``--today-ms``, an assumed
quiet-machine step of today's file, 15.5 ms as docs/latency.md measured it on 2026-12-05, since this
machine's load makes the absolute step of one run meaningless).
The candidate a ship check should try next is the fastest whose every row is within spread
(`ship_candidate`); the ship rule itself is `benchmarks/scorecard.py --candidate-dir` on fresh seeds.
"""
from __future__ import annotations

import argparse
import json
import random
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from types import SimpleNamespace

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SHIPPED = ROOT / "sdk" / "radar_odom" / "models" / "cart-0.4.onnx"
PAPER_GPU_MS = 16.9  # the paper's step at 0.4 m on a Titan Xp (docs/latency.md)
TODAY_QUIET_MS = 15.5  # today's cart-0.4 graph step, 2 threads, quiet machine (docs/latency.md, 2026-12-05)
KITTI_ROW = "sim all: translation %"
SUMMARY_ROWS = (KITTI_ROW, "sim all: rotation °/m", "sim urban: translation %", "sim heavy_traffic: translation %",
                "sim open: translation %", "sim highway: translation %",
                "real drive whole: translation %", "real drive held-out (last 80): translation %",
                "real Oxford pair: |1 − x/true|", "real Oxford pair: |yaw error| °")
REAL_DRIVE = ROOT.parent / "shared" / "data" / "real" / "radiate-2019-02-12-edinburgh"

# name -> how it is built: "shipped", or {"settings": fast-search label or None, "quantize": exclude or None}
CANDIDATES = {
    "today": {"what": "the shipped cart-0.4.onnx (fast search c4s3b2, float32)", "build": "shipped"},
    "int8-ff": {"what": "static QDQ int8 masker, per channel, first/last Conv float32, calibrated sim + real",
                "settings": None, "quantize": "first,last"},
    "int8-all": {"what": "static QDQ int8 masker, per channel, every Conv int8, calibrated sim + real",
                 "settings": None, "quantize": ""},
    "c4s4b2": {"what": "re-export, coarse stage every 4th yaw (float32)", "settings": "c4s4b2", "quantize": None},
    "c4s6b2": {"what": "re-export, coarse stage every 6th yaw (float32)", "settings": "c4s6b2", "quantize": None},
    "c4s4b2+int8-ff": {"what": "c4s4b2 with the int8-ff masker", "settings": "c4s4b2", "quantize": "first,last"},
    "c4s6b2+int8-ff": {"what": "c4s6b2 with the int8-ff masker", "settings": "c4s6b2", "quantize": "first,last"},
    "mask-md4": {"what": "the masker on a grid 4x coarser (1.6 m/px; today's runs it 2x coarser, 0.8 m/px), its "
                         "mask upsampled; the shipped weights, not trained for that scale; c4s3b2, float32",
                 "settings": "c4s3b2", "quantize": None, "mask_downsample": 4},
}
NOT_BUILT = {
    "half-resolution masker, trained": "today's cart-0.4 already runs its masker at half the grid's resolution "
                                       "(profile mask_downsample 2: 0.8 m/px); the next halving is built untrained "
                                       "(mask-md4); one trained or distilled for it (train --mask-downsample 4) "
                                       "needs a training run: not built here, not measured",
    "coarse-to-fine translation": "the graphs have no coarse translation stage to drop to (the correlation is "
                                  "one full-resolution DFT per yaw in the band); a new search, not built here, "
                                  "not measured",
}


# ----------------------------------------------------------------------------- pure parts (tested)
def parse_setting(label: str) -> dict:
    """``c4s6b2`` -> the fast search's settings dict (as the shipped metadata writes it)."""
    try:
        c, rest = label[1:].split("s")
        s, b = rest.split("b")
        if label[0] != "c":
            raise ValueError
        return {"coarse_factor": int(c), "coarse_stride": int(s), "band_half_width": int(b), "rotation": "polar"}
    except ValueError:
        raise SystemExit(f"bad setting {label!r}: write c<factor>s<stride>b<half-width>, e.g. c4s4b2") from None


def paper_half_ratio(today_ms: float = TODAY_QUIET_MS, paper_ms: float = PAPER_GPU_MS) -> float:
    """Half the paper's GPU step as a ratio to today's step (0.5 × 16.9 / 15.5 = 0.545)."""
    return 0.5 * paper_ms / today_ms


def pareto(points: dict) -> list[str]:
    """Names of the points {name: (step ratio, error)} no other point beats on both (ties kept), fastest first."""
    out = []
    for n, (t, e) in points.items():
        if not any((t2 <= t and e2 <= e) and (t2 < t or e2 < e) for m, (t2, e2) in points.items() if m != n):
            out.append(n)
    return sorted(out, key=lambda n: points[n][0])


def ship_candidate(rows: dict, reference: str = "today") -> str | None:
    """The fastest candidate (median step ratio) other than ``reference`` with no row worse beyond its spread
    and faster than the reference; ``rows``: {name: {"ratio": float, "worse": int}}. None if there is none."""
    ok = [n for n, r in rows.items() if n != reference and r.get("worse") == 0 and r["ratio"] < 1.0]
    return min(ok, key=lambda n: rows[n]["ratio"]) if ok else None


def ratio_stats(times_ref, times, rng: np.random.Generator, reps: int = 400) -> dict:
    """Median and p10 ratio of ``times`` to ``times_ref`` (seconds per step), and a bootstrap spread of the first."""
    a, b = np.asarray(times_ref, float), np.asarray(times, float)
    boot = [np.median(rng.choice(b, b.size)) / np.median(rng.choice(a, a.size)) for _ in range(reps)]
    return {"ratio": float(np.median(b) / np.median(a)), "ratio_spread": float(np.std(boot, ddof=1)),
            "p10_ratio": float(np.percentile(b, 10) / np.percentile(a, 10)),
            "median_ms": float(1e3 * np.median(b)), "p10_ms": float(1e3 * np.percentile(b, 10))}


def fmt_row(value_spread) -> str:
    v, s = value_spread[:2]
    return "n/a" if not np.isfinite(v) else f"{v:.3g} ± {s:.2g}"


def table(result: dict) -> str:
    """The markdown table of a run's ``result`` (frontier.json)."""
    names = [n for n in result["candidates"] if n in result["timing"] and n in result["rows"]]
    cols = [r for r in SUMMARY_ROWS if any(r in result["rows"][n] for n in names)]
    short = {KITTI_ROW: "sim all t %", "sim all: rotation °/m": "sim all °/m",
             "real drive whole: translation %": "real whole t %",
             "real drive held-out (last 80): translation %": "real held-out t %",
             "real Oxford pair: |1 − x/true|": "Oxford |1 − x/true|",
             "real Oxford pair: |yaw error| °": "Oxford |yaw err| °"}
    head = ["candidate", "step / today (median)", "p10 ratio", *[short.get(c, c.replace(": translation %", " t %"))
                                                                  for c in cols], "rows worse / of"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for n in names:
        t, rows = result["timing"][n], result["rows"][n]
        worse = result["verdicts"][n]
        lines.append("| " + " | ".join([
            f"{n}", f"{t['ratio']:.3f} ± {t['ratio_spread']:.2g}", f"{t['p10_ratio']:.3f}",
            *[fmt_row(rows[c]) if c in rows else "—" for c in cols],
            "—" if n == "today" else f"{len(worse['worse'])} / {worse['rows']}"]) + " |")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- building
def build(name: str, out_dir: Path, log) -> Path:
    """``OUT/candidates/NAME.onnx``, built now unless it is there already."""
    spec = CANDIDATES[name]
    if spec.get("build") == "shipped":
        return SHIPPED
    if spec.get("build") == "file":  # --extra NAME=PATH: a graph built elsewhere (e.g. a trained masker)
        return Path(spec["path"])
    down = spec.get("mask_downsample")
    src = out_dir / f"{f'md{down}-' if down else ''}{spec['settings']}.onnx" if spec["settings"] else SHIPPED
    path = out_dir / f"{name}.onnx" if spec["quantize"] is not None else src  # a float32 export is its own file
    if path.is_file():
        return path
    t0 = time.perf_counter()
    if spec["settings"]:
        if not src.is_file():
            from radar_odom_export.checkpoint import read_checkpoint_dict, resolve_checkpoint, write_checkpoint_dict
            from radar_odom_export.onnx_export import export_checkpoint

            ckpt = resolve_checkpoint("cart-0.4")
            if down:  # the shipped checkpoint with its masker on a coarser grid (the profile's field)
                d = read_checkpoint_dict(ckpt)
                d["profile"] = {**d["profile"], "mask_downsample": int(down)}
                ckpt = write_checkpoint_dict(out_dir / f"cart-0.4-md{down}.pt", d)
            rep = export_checkpoint(ckpt, src, form="stream", search="fast",
                                    search_settings=parse_setting(spec["settings"]), verify=True)
            log(rep.summary())
            if not down:
                check_same_metadata(src, SHIPPED)
    if spec["quantize"] is not None:
        from radar_odom_export.quantize import quantize_model

        real = [REAL_DRIVE] if REAL_DRIVE.is_dir() else []
        rep = quantize_model(src, path, real=real, exclude=spec["quantize"], threads=1)
        log(rep.summary())
    log(f"built {name} in {time.perf_counter() - t0:.0f} s")
    return path


def check_same_metadata(path: Path, shipped: Path) -> None:
    """A re-export must carry the shipped file's metadata (profile, calibration, training data) but its search
    (and the checkpoint's file name, the exporter and torch versions)."""
    from radar_odom.onnx_model import OnnxModel

    a = dict(OnnxModel(path).session.get_modelmeta().custom_metadata_map)
    b = dict(OnnxModel(shipped).session.get_modelmeta().custom_metadata_map)
    skip = {"radar_odom.search", "radar_odom.torch_version", "radar_odom.exporter"}
    for m in (a, b):  # the checkpoint's file name (the shipped file was written from a calibrated copy, cal.pt)
        m["radar_odom.training_data"] = {k: v for k, v in json.loads(m.get("radar_odom.training_data") or "{}").items()
                                         if k != "checkpoint"}
    diff = sorted(k for k in set(a) | set(b) if k not in skip and a.get(k) != b.get(k))
    if diff:
        sys.exit(f"{path}: metadata differs from the shipped file's in {diff}: not the shipped model re-exported")


# ----------------------------------------------------------------------------- accuracy (scorecard's functions)
def measure_one(job) -> dict:
    """Poses of one candidate over the run's drives (a worker process)."""
    import warnings

    sys.path.insert(0, str(HERE))
    import scorecard as sc

    from radar_odom.errors import StampWarning

    name, model, data = job
    warnings.simplefilter("ignore", StampWarning)
    t0 = time.perf_counter()
    res = sc.measure_sim(model, {}, data)
    res["real"] = sc.measure_real(model, {})
    return {"name": name, "res": res, "seconds": time.perf_counter() - t0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="The module docstring says what each column measures.")
    ap.add_argument("-o", "--out", type=Path, required=True, help="output folder (candidates are cached there)")
    ap.add_argument("--only", default=None, help="comma-separated candidate names (default: all; today always)")
    ap.add_argument("--seeds", type=int, default=None, help="seed generator (default: drawn now, printed)")
    ap.add_argument("--drives", type=int, default=2, help="simulated drives per scenario (default: %(default)s)")
    ap.add_argument("--frames", type=int, default=240, help="sweeps per scenario drive (default: %(default)s)")
    ap.add_argument("--bend-drives", type=int, default=2, help="drives per bend rate (default: %(default)s)")
    ap.add_argument("--bend-frames", type=int, default=28, help="sweeps per bend drive (default: %(default)s)")
    ap.add_argument("--steps", type=int, default=300, help="interleaved timed steps per graph (default: %(default)s)")
    ap.add_argument("--jobs", type=int, default=2, help="processes for the accuracy runs (default: %(default)s)")
    ap.add_argument("--today-ms", type=float, default=TODAY_QUIET_MS,
                    help="today's quiet-machine step, for the half-paper line (default: %(default)s, assumed)")
    ap.add_argument("--extra", action="append", default=[], metavar="NAME=PATH.onnx",
                    help="also a graph built elsewhere (a cart-0.4 stream file, e.g. a masker trained with train "
                         "--mask-downsample 4), as candidate NAME; repeatable")
    ap.add_argument("--build-only", action="store_true", help="build the candidates and stop")
    ap.add_argument("--replot", action="store_true",
                    help="redraw OUT/frontier.png from OUT/frontier.json, measure nothing")
    args = ap.parse_args(argv)
    if args.replot:
        plot(json.loads((args.out / "frontier.json").read_text()), args.out / "frontier.png")
        return 0
    for item in args.extra:
        name, _, path = item.partition("=")
        if not name or not path.endswith(".onnx") or not Path(path).is_file():
            ap.error(f"--extra {item!r}: give NAME=PATH.onnx of an existing file")
        CANDIDATES[name] = {"what": f"a graph built elsewhere: {Path(path).name}", "build": "file", "path": path}
    names = list(CANDIDATES) if not args.only else ["today", *[n for n in args.only.split(",") if n != "today"]]
    unknown = [n for n in names if n not in CANDIDATES]
    if unknown:
        ap.error(f"unknown candidates {unknown}; known: {list(CANDIDATES)}")
    if args.seeds is None:
        args.seeds = random.SystemRandom().randint(0, 2**31 - 1)
    out = args.out
    (out / "candidates").mkdir(parents=True, exist_ok=True)
    log_path = out / "frontier.log"

    def log(msg: str) -> None:
        print(msg, flush=True)
        with open(log_path, "a") as fh:
            fh.write(msg + "\n")

    log(f"frontier: seed generator {args.seeds} (repeat with --seeds {args.seeds}); candidates {names}")
    paths = {n: build(n, out / "candidates", log) for n in names}
    if args.build_only:
        return 0

    sys.path.insert(0, str(HERE))
    import warnings

    import scorecard as sc
    from compare_graphs import interleaved_times

    from radar_odom.errors import StampWarning
    from radar_odom.evaluation.reference import gnss_reference
    from radar_odom.io import read_sequence

    record_path = out / f"accuracy-{args.seeds}.json"
    record = json.loads(record_path.read_text()) if record_path.is_file() else {"measured": {}}
    data_root = out / f"data-{args.seeds}"
    if "data" not in record:
        data_root.mkdir(exist_ok=True)
        ns = SimpleNamespace(seeds=args.seeds, drives=args.drives, frames=args.frames, bend_drives=args.bend_drives,
                             bend_frames=args.bend_frames, jobs=args.jobs)
        record["data"] = sc.build_data(ns, data_root)
        record["size"] = {"drives": args.drives, "frames": args.frames, "bend_drives": args.bend_drives,
                          "bend_frames": args.bend_frames}
        record_path.write_text(json.dumps(record))
    data = record["data"]
    log("fresh seeds: " + ", ".join(f"{d['scenario']} {d['seed']}" for d in data["sim"]) + "; straight "
        + ", ".join(str(d["seed"]) for d in data["straight"]) + "; bends "
        + ", ".join(f"{d['rate']:g}° {d['seed']}" for d in data["bends"]))
    warnings.simplefilter("ignore", StampWarning)
    if "clock" not in record:  # the real drive's reference clock: found once, from today's file, used for all
        clock = None
        if REAL_DRIVE.is_dir():
            seq = read_sequence(REAL_DRIVE)
            poses, _ = sc.run_scans(str(SHIPPED), {}, (f.scan for f in seq), seq)
            clock = gnss_reference(seq.reference, seq.timestamps_us, poses, time_base=seq.time_base)[1][
                "clock_offset_s"]
        record["clock"] = clock
        record_path.write_text(json.dumps(record))
    todo = [(n, str(paths[n]), data) for n in names if n not in record["measured"]]
    if todo:
        with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
            for r in pool.map(measure_one, todo):
                record["measured"][r["name"]] = r["res"]
                record_path.write_text(json.dumps(record))
                log(f"  {r['name']}: accuracy measured in {r['seconds']:.0f} s")
    truth = sc.load_truth(data, record["clock"])
    rows, verdicts = {}, {}
    for n in names:
        rows[n] = sc.rows_for(record["measured"][n], truth, data, np.random.default_rng(args.seeds))
    for n in names:
        v = {row: sc.verdict(rows["today"][row], rows[n][row]) for row in rows["today"]}
        verdicts[n] = {"rows": len(v), "worse": [r for r, x in v.items() if x == "**worse**"],
                       "better": [r for r, x in v.items() if x == "better"]}

    log(f"timing {len(names)} graphs interleaved, {args.steps} steps each, 2 threads ...")
    times = interleaved_times([str(paths[n]) for n in names], steps=args.steps, warmup=20, threads=2)
    rng = np.random.default_rng(args.seeds)
    timing = {n: ratio_stats(times[0], t, rng) for n, t in zip(names, times)}
    for n in names:
        timing[n]["bytes"] = Path(paths[n]).stat().st_size
    result = {"seeds": args.seeds, "size": record["size"], "candidates": names,
              "what": {n: CANDIDATES[n]["what"] for n in names}, "not_built": NOT_BUILT,
              "timing": timing, "rows": {n: {k: list(v) for k, v in r.items()} for n, r in rows.items()},
              "verdicts": verdicts, "today_ms_assumed": args.today_ms,
              "half_paper_ratio": paper_half_ratio(args.today_ms),
              "clock_offset_s": record["clock"], "data": data,
              "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    summary = {n: {"ratio": timing[n]["ratio"], "worse": len(verdicts[n]["worse"])} for n in names}
    result["ship_candidate"] = ship_candidate(summary)
    points = {n: (timing[n]["ratio"], rows[n][KITTI_ROW][0]) for n in names}
    result["pareto"] = pareto(points)
    (out / "frontier.json").write_text(json.dumps(result, indent=1))
    text = [f"Seed generator {args.seeds}; {args.drives} drives × {len(sc.SCENARIOS)} scenarios × {args.frames} "
            f"sweeps, bends {args.bend_drives} × {args.bend_frames}; {args.steps} interleaved steps per graph, "
            f"2 threads; today's step in this run: median {timing['today']['median_ms']:.1f} ms, "
            f"p10 {timing['today']['p10_ms']:.1f} ms (the machine is shared: ratios only).", "", table(result), "",
            "Rows worse than today's beyond their spread: " + "; ".join(
                f"{n}: {', '.join(verdicts[n]['worse']) or 'none'}" for n in names if n != "today"),
            f"Pareto (step ratio vs sim KITTI t %): {', '.join(result['pareto'])}.",
            f"Fastest with every row within spread: {result['ship_candidate'] or 'none'}.",
            f"Half the paper's GPU step (0.5 × {PAPER_GPU_MS} ms) as a ratio to today's step, assuming today's quiet "
            f"step is {args.today_ms} ms: {result['half_paper_ratio']:.3f}.", "",
            "Not built: " + "; ".join(f"{k}: {v}" for k, v in NOT_BUILT.items()) + "."]
    (out / "frontier.md").write_text("\n".join(text) + "\n")
    print("\n".join(text))
    plot(result, out / "frontier.png")
    return 0


def plot(result: dict, path: Path) -> None:
    """Two panels: the step ratio against the simulated KITTI translation error, with the half-paper line (left),
    and the candidates' corner against the real drive's (right); one colour and marker per candidate."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    real_row = "real drive whole: translation %"
    fig, axes = plt.subplots(1, 2, figsize=(9.6, 4.0), dpi=90, gridspec_kw={"width_ratios": [1.2, 1]})
    markers = "osD^v<>ph*"
    for i, n in enumerate(result["candidates"]):
        t = result["timing"][n]
        worse = bool(result["verdicts"][n]["worse"])
        style = dict(fmt=markers[i % len(markers)], color=f"C{i}", capsize=2, ms=6,
                     mfc="none" if worse else f"C{i}")
        k = len(result["verdicts"][n]["worse"])
        label = n + (f" ({k} row{'s' if k > 1 else ''} worse)" if worse else "")
        v, s = result["rows"][n][KITTI_ROW][:2]
        axes[0].errorbar(t["ratio"], v, xerr=t["ratio_spread"], yerr=s, label=label, **style)
        if real_row in result["rows"][n] and not worse:  # the zoom: candidates with every row within spread
            v, s = result["rows"][n][real_row][:2]
            axes[1].errorbar(t["ratio"], v, xerr=t["ratio_spread"], yerr=s, **style)
    half = result["half_paper_ratio"]
    axes[0].axvline(half, color="grey", ls="--")
    axes[0].text(half + 0.01, axes[0].get_ylim()[0], f"0.5 × paper GPU step\n(assumes today's step\n"
                 f"= {result['today_ms_assumed']:g} ms)", fontsize=7, va="bottom")
    axes[0].set_xlim(min(half - 0.05, axes[0].get_xlim()[0]), 1.05)
    axes[0].set_xlabel("graph step / today's cart-0.4 (median, interleaved, 2 threads)", fontsize=8)
    axes[0].set_ylabel("simulated drives: KITTI translation error (%)", fontsize=8)
    axes[0].legend(fontsize=7, loc="upper left")
    axes[1].set_xlabel("graph step / today's (zoom: candidates with no row worse)", fontsize=8)
    axes[1].set_ylabel("real RADIATE drive (whole): KITTI translation (%)", fontsize=8)
    fig.suptitle(f"cart-0.4 speed–accuracy frontier, {result['date']}, seeds {result['seeds']} "
                 "(bars: the scorecard's spreads)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())

"""Where the yaw pull comes from: the same masked sweeps, rotated in different ways, read by argmax.

    python benchmarks/yaw_kernels.py                       # cart-0.4 checkpoint, seed 5150's curve; ≈ 2 min
    python benchmarks/yaw_kernels.py --checkpoint cart-0.8 --pairs 12

A simulated drive (``--seed`` 5150, urban) turns 0.36–0.64 °/sweep from pair 34 on. For each of its
turning pairs the checkpoint's masker makes both sweeps' features once; the current sweep's
features are then rotated by yaw candidates every half yaw step (±2° around 0; the profile's
step is 0.5°) in each of these ways, correlated with the previous sweep's over the
translation window (numpy FFT), and the yaw read as the parabola peak of the best score per
candidate. The slope (Σ est·true / Σ true²) says how much of the turn each way reads:

* ``polar bilinear`` / ``polar cubic``: the graph's `PolarRotator` (Cartesian → polar grid → back),
  each kernel with as many grid rows per candidate as the graph has per yaw step
  (`correlation.POLAR_GRIDS`), so that every candidate is a whole-row roll;
* ``OpenCV bilinear`` / ``cubic`` / ``Lanczos-4``: one direct ``cv2.warpAffine`` rotation;
* ``Fourier (exact)``: three Fourier shears, no interpolation kernel at all;
* ``drawn per candidate``: the current sweep drawn from its polar data in a frame turned by the
  candidate, and masked anew: what no single rotation of one feature image can do.

Torch (the masker) and the export extra; the simulator writes nothing to disk.
"""
from __future__ import annotations

import argparse
import math
import sys

import numpy as np


def rotate_fft(img: np.ndarray, yaw: float) -> np.ndarray:
    """``img`` turned by ``yaw`` (output pixel p samples the input at R(yaw)ᵀ p) with three Fourier shears."""
    w = img.shape[0]
    a = np.pad(img, w // 2)
    n = a.shape[0]
    c = (n - 1) / 2
    k = np.fft.fftfreq(n)
    pos = np.arange(n) - c

    def shear(arr, s, axis):
        spec = np.fft.fft(arr, axis=axis)
        phase = np.exp(-2j * np.pi * (k[None, :] * s * pos[:, None] if axis == 1 else k[:, None] * s * pos[None, :]))
        return np.real(np.fft.ifft(spec * phase, axis=axis))

    t, s = math.tan(-yaw / 2), math.sin(-yaw)
    out = shear(shear(shear(a, t, 1), -s, 0), t, 1)
    return out[w // 2: w // 2 + w, w // 2: w // 2 + w]


def rotate_cv(img: np.ndarray, yaw: float, flag: int) -> np.ndarray:
    import cv2

    w = img.shape[0]
    c = (w - 1) / 2
    co, si = math.cos(yaw), math.sin(yaw)
    m = np.array([[co, si, c - co * c - si * c], [-si, co, c + si * c - co * c]])
    return cv2.warpAffine(img, m, (w, w), flags=flag | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT)


def best_scores(prev: np.ndarray, rotated: list[np.ndarray], n: int) -> np.ndarray:
    """float[K]: the best translation score of each rotated current image against ``prev``."""
    p = np.conj(np.fft.rfft2(prev))
    w = prev.shape[0]
    out = []
    for r in rotated:
        full = np.fft.irfft2(p * np.fft.rfft2(r), s=(w, w))
        out.append(np.roll(full, (n, n), axis=(0, 1))[: 2 * n + 1, : 2 * n + 1].max())
    return np.array(out)


def parabola_peak(v: np.ndarray) -> float:
    k = int(np.argmax(v))
    if 0 < k < len(v) - 1:
        den = v[k - 1] - 2 * v[k] + v[k + 1]
        if den < 0:
            return k + float(np.clip(0.5 * (v[k - 1] - v[k + 1]) / den, -0.5, 0.5))
    return float(k)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", default="cart-0.4", help="shipped name or checkpoint (default: %(default)s)")
    ap.add_argument("--seed", type=int, default=5150, help="urban drive seed (default: %(default)s)")
    ap.add_argument("--pairs", type=int, default=34, help="turning pairs used (default: %(default)s)")
    args = ap.parse_args(argv)

    import cv2
    import torch

    from radar_odom.odometry.sweep_input import SweepMotion, graph_input
    from radar_odom.sim.simulator import simulate_drive
    from radar_odom_export.checkpoint import load_checkpoint, resolve_checkpoint
    from radar_odom_export.correlation import polar_rotator

    model, _ = load_checkpoint(resolve_checkpoint(args.checkpoint))
    p = model.profile
    info = type("Info", (), {"profile": p, "polar_input": None})()
    frames = list(simulate_drive(args.seed, 34 + args.pairs + 1, "urban"))
    scans = [f.scan for f in frames]
    truth = np.array([f.pose_rel[2] for f in frames[1:]])
    pairs = [i for i in range(len(truth)) if abs(math.degrees(truth[i])) > 0.3][: args.pairs]
    n, q = p.translation_cells, p.rotation_step_rad / 2  # candidates every half yaw step
    shifts = list(range(-8, 9))

    def features(x):
        with torch.no_grad():
            return model.sweep_features(torch.from_numpy(x))[0].numpy()

    feats = {i: features(graph_input(scans[i], info)) for i in sorted({*pairs, *(i + 1 for i in pairs)})}
    disc = (p.width_px - 1) / 2 - n

    def polar(kernel):
        # a grid with each kernel's rows per candidate as the graph's has per yaw step (`POLAR_GRIDS`)
        rot = polar_rotator(p.width_px, q, disc, 8, kernel)
        return lambda img: rot.rotate_constant(torch.from_numpy(img)[None], shifts)[0].numpy()

    ways = {
        "polar bilinear (graph, before)": polar("bilinear"),
        "polar cubic (graph, now)": polar("cubic"),
        "OpenCV bilinear": lambda img: [rotate_cv(img, s * q, cv2.INTER_LINEAR) for s in shifts],
        "OpenCV cubic": lambda img: [rotate_cv(img, s * q, cv2.INTER_CUBIC) for s in shifts],
        "OpenCV Lanczos-4": lambda img: [rotate_cv(img, s * q, cv2.INTER_LANCZOS4) for s in shifts],
        "Fourier (exact)": lambda img: [rotate_fft(img, s * q) for s in shifts],
    }
    print(f"{args.checkpoint}: seed {args.seed}, {len(pairs)} turning pairs, true yaw "
          f"{math.degrees(truth[pairs].min()):.2f}–{math.degrees(truth[pairs].max()):.2f}°", flush=True)
    rows = []
    for name, rotate in ways.items():
        est = np.array([(parabola_peak(best_scores(feats[i], rotate(feats[i + 1]), n)) - 8) * q for i in pairs])
        rows.append((name, float(np.sum(est * truth[pairs]) / np.sum(truth[pairs] ** 2))))
        print(f"| {rows[-1][0]} | {rows[-1][1]:.2f} |", flush=True)
    drawn = []
    for i in pairs:
        rotated = [features(graph_input(scans[i + 1], info, SweepMotion(frame_pose=(0.0, 0.0, -s * q))))
                   for s in shifts]
        drawn.append((parabola_peak(best_scores(feats[i], rotated, n)) - 8) * q)
    rows.append(("drawn per candidate (masked anew)", float(np.sum(np.array(drawn) * truth[pairs])
                                                            / np.sum(truth[pairs] ** 2))))
    print("\n| rotation of the current sweep's features | estimated / true yaw |\n|---|---:|")
    for name, slope in rows:
        print(f"| {name} | {slope:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

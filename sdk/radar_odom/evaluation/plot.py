"""The run's picture: the path seen from above and the heading over time, estimate vs reference."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def plot_trajectory(path, est_poses: np.ndarray, gt_poses: np.ndarray | None, timestamps_us, title: str) -> Path:
    """PNG of the path seen from above (x, −y) and heading (−yaw) over time, estimate vs truth."""
    try:
        import matplotlib
    except ImportError:
        from ..errors import MissingExtraError

        raise MissingExtraError("matplotlib", "cli") from None
    matplotlib.use("Agg")  # files only: never needs a display
    import matplotlib.pyplot as plt

    from ..se2 import to_xyyaw

    t_s = (np.asarray(timestamps_us) - timestamps_us[0]) * 1e-6
    fig, (ax_map, ax_yaw) = plt.subplots(1, 2, figsize=(12, 5.5), gridspec_kw={"width_ratios": [3, 2]})
    curves = [("estimate", est_poses, "tab:blue")]
    if gt_poses is not None:
        curves.insert(0, ("ground truth", gt_poses, "k"))
    for label, poses, colour in curves:
        xyyaw = to_xyyaw(poses)
        ax_map.plot(xyyaw[:, 0], -xyyaw[:, 1], color=colour, label=label, lw=1.5)
        ax_yaw.plot(t_s, np.degrees(-np.unwrap(xyyaw[:, 2])), color=colour, label=label, lw=1.5)
    ax_map.plot([0], [0], "o", color="tab:green", label="start")
    ax_map.set_aspect("equal", adjustable="datalim")
    ax_map.set_xlabel("x (m, forward at start)")
    ax_map.set_ylabel("−y (m, left at start)")
    ax_map.legend(loc="best")
    ax_map.grid(alpha=0.3)
    ax_yaw.set_xlabel("time (s)")
    ax_yaw.set_ylabel("heading −yaw (deg)")
    ax_yaw.grid(alpha=0.3)
    fig.suptitle(f"{title}\nmap view from above (z up): y and yaw negated from the x-fwd/y-right/z-down frame")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)



"""What each column of ``radar-odom profile``'s tables means: one list, read by the report's
legend and by ``radar-odom profile --help`` (so the two never disagree)."""
from __future__ import annotations

# (header, meaning) of the latency table, in its order
LATENCY_COLUMNS = (
    ("model", "the model profiled: a shipped name, an .onnx file's stem, or PROFILE (untrained): an untrained "
              "export of that grid, timed only"),
    ("grid", "the Cartesian grid the graph correlates: metres per pixel × pixels per side"),
    ("search", "the rotation search in the file: exhaustive (every yaw candidate), coarse-to-fine (the fast "
               "search: a coarse yaw pick, then a band of yaws at full resolution) or decoupled"),
    ("PNG decode", "ms to decode one Oxford-layout sweep PNG (cv2.imdecode)"),
    ("sweep parse", "ms to turn the decoded pixels into a RadarScan (timestamps, angles, power)"),
    ("polar→Cartesian", "ms for the graph's input: the sweep resampled onto the grid (the runtime's own "
                        "conversion; 'p2c' in the printed summary lines)"),
    ("graph", "ms of one onnxruntime run: masker, rotations, correlation, pose and covariance"),
    ("step (p→C + graph)", "polar→Cartesian + graph, one sweep at a time: what the paper times on its GPU"),
    ("paper GPU step", "the paper's Titan Xp time for a step at that resolution, ms"),
    ("graph / numpy-FFT exhaustive", "graph median ÷ the median of the same masked images searched over every "
                                     "yaw candidate in numpy (pocketfft) and OpenCV; the reference has no masker"),
    ("graph / numpy-FFT same search", "graph median ÷ the numpy twin of the file's own search (fast or decoupled)"),
    ("search only / numpy-FFT same search", "(graph − its masker operators, from the traced runs) ÷ that same "
                                            "numpy search: search against search"),
    ("process peak RSS MiB", "the profiling process's peak resident memory so far (cumulative over the models "
                             "profiled before this row)"),
)

# the end-to-end table: sweep files read back from disk through radar_odom.iter_estimates
FILE_COLUMNS = (
    ("pipelined sweeps/s", "sweeps per second through iter_estimates, the next sweep read on a worker thread "
                           "while the graph runs (a separate stream from the timed steps: its own load)"),
    ("ms per sweep", "1000 / pipelined sweeps/s: the wall time per sweep of that stream"),
    ("read median", "median ms to read one sweep file in that stream (decode + parse)"),
    ("step median", "median ms of RadarOdometer.step in that stream (polar→Cartesian, graph, fusion)"),
    ("ratio", "ms per sweep ÷ max(read median, step median); 1.0 is perfect overlap"),
    ("serial sweeps/s", "the same stream with no worker thread (read, then step)"),
    ("serial ratio", "the serial stream's ratio"),
)


def legend(columns) -> list[str]:
    """Markdown bullet lines, one per column."""
    return [f"- *{head}*: {meaning}" for head, meaning in columns]


def help_text() -> str:
    """The columns of both tables, as ``--help`` prints them."""
    lines = ["columns of profile.md's latency table (median / p90 / p99 ms over the timed steps):"]
    lines += [f"  {head}: {meaning}" for head, meaning in LATENCY_COLUMNS]
    lines += ["columns of its end-to-end table (sweep files from disk):"]
    lines += [f"  {head}: {meaning}" for head, meaning in FILE_COLUMNS]
    return "\n".join(lines)

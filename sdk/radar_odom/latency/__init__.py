"""CPU latency of the runtime, per stage and per operator class, with a numpy-FFT reference.

``radar-odom profile`` (`run_profile`) streams simulated sweeps through one exported model per
grid profile and times each stage of a step as the runtime performs it:

* ``png_decode``: ``cv2.imdecode`` of an Oxford-layout sweep PNG (400 × 3779 bytes);
* ``sweep_parse``: header columns → `RadarScan` (timestamps, encoder angles, power / 255);
* ``polar_to_cartesian``: the graph's input (`RadarOdometer`'s own conversion);
* ``graph``: one onnxruntime run (masker, rotations, correlation, soft-argmax);
* ``step`` = polar→Cartesian + graph (what the paper times on its GPU), ``full`` = all four.

Each is summarised as median / p90 / p99 (ms) over the timed steps after a warm-up.
Inside the graph, onnxruntime's own profiler (``SessionOptions.enable_profiling``) is run on a
separate session, its JSON trace parsed and node times grouped by operator class per run
(`operator_profile`), so the timed session is not slowed by tracing.

**Reference** (`FFTReference`): the same search written with numpy's pocketfft (``rfft2`` /
``irfft2``) and OpenCV's bilinear ``warpAffine`` on the *same masked images* — recovered from
the graph's own stream state (the masked sweep's half spectrum) with ``irfft2``. Two variants
are timed: the exhaustive search over every candidate of the profile, and, for models exported
with the fast search (``radar_odom.search`` metadata), the same coarse-to-fine search, or for
the decoupled search its numpy twin (`reference.DecoupledReference`: ``rfft`` along angles,
numpy bilinear resampling and rotation). The
report gives graph time / reference time. The reference covers the search only (no masker).

**Memory**: peak RSS (``VmHWM``) of the process, and `rss_stream`, which runs a long stream
through `RadarOdometer` in a fresh interpreter (nothing else loaded) and samples ``VmRSS``.

Models: shipped ones by name, ``.onnx`` paths, or for a profile with neither, an untrained
model exported on the fly (needs torch, imported only in a child process; this module never
imports torch).

Modules: `stats` (summaries, memory, machine, trace parsing), `reference` (the numpy search),
`sweeps` (what is timed), `timing` (one model), `memory` (a long stream), `models` (which
models), `runner` (the whole run and its report). "Latency" names this package so that
"profile" keeps one meaning in the code: a `GridProfile`.
"""
from __future__ import annotations

from .runner import DEFAULT_PROFILES, PAPER_GPU_MS, markdown_report, run_profile

__all__ = ["DEFAULT_PROFILES", "PAPER_GPU_MS", "markdown_report", "run_profile"]

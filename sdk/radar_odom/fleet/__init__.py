"""`radar-odom fleet`: `radar-odom run` over many recordings as Ray tasks, resumable, with a fleet report.

- `manifest`: when a recording's outputs are done (a key over inputs, model and options; file digests).
- `job`: one recording, written atomically (no Ray).
- `scheduler`: the Ray actor pool (one onnxruntime session per worker), retries, progress (needs the
  ``fleet`` extra; imported only where used).
- `report`: ``fleet.csv`` and ``fleet.md`` with its plot.
"""

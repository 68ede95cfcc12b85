"""Radar sweep files of the Oxford, Boreas, MulRan and RADIATE datasets, and recording folders.

- `load_scan` reads one sweep PNG of any of the four datasets into a `RadarScan`;
  `write_scan` writes the Oxford layout (byte-exact round trip).
- `read_sequence` opens a recording: time-ordered, lazily decoded sweeps with ground truth in
  the Oxford relative-pose convention.
- `write_radar_timestamps`, `oxford_gt_rows`, `write_oxford_ground_truth` write the rest of an
  Oxford recording (used by the simulator).

One module per dataset (`oxford`, `boreas`, `mulran`, `radiate`); the shared PNG row header is
`_layout`. `gnss_ins` reads RADIATE's GNSS/INS samples (``Sequence.reference``) and gives
reference poses at radar times once its clock and heading offsets are known.
"""
from .oxford import oxford_gt_rows, write_oxford_ground_truth, write_radar_timestamps, write_scan
from .scan_io import FORMATS, detect_format, load_scan
from .sequence import Frame, Sequence, read_sequence

__all__ = [
    "FORMATS",
    "Frame",
    "Sequence",
    "detect_format",
    "load_scan",
    "oxford_gt_rows",
    "read_sequence",
    "write_oxford_ground_truth",
    "write_radar_timestamps",
    "write_scan",
]

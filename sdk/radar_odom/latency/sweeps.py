"""Sweeps to time: simulated Oxford-layout PNG bytes, and the reader's own decode and parse."""
from __future__ import annotations

import numpy as np

from ..errors import RadarOdomError

PROFILE_SEED = 4242  # the simulated drive the sweeps come from (content barely matters for speed)


def simulated_pngs(count: int, seed: int = PROFILE_SEED, scenario: str = "urban") -> list[bytes]:
    """``count`` simulated sweeps encoded as Oxford-layout PNG bytes (what a recording holds)."""
    import cv2

    from ..io.oxford import scan_to_image
    from ..sim import simulate_drive

    out = []
    for frame in simulate_drive(seed, count, scenario):
        ok, buf = cv2.imencode(".png", scan_to_image(frame.scan))
        if not ok:
            raise RadarOdomError("OpenCV could not encode a simulated sweep as PNG")
        out.append(buf.tobytes())
    return out


def decode_png(data: bytes) -> np.ndarray:
    import cv2

    img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise RadarOdomError("a sweep PNG could not be decoded")
    return img


def parse_sweep(img: np.ndarray, source: str = "profile"):
    """Oxford-layout pixels → `RadarScan` (the reader's own parsing)."""
    from ..io._layout import scan_from_header_image
    from ..scan import OXFORD_RANGE_RESOLUTION_M

    return scan_from_header_image(img, source, use_valid_column=True,
                                  range_resolution_m=OXFORD_RANGE_RESOLUTION_M, range_offset_m=0.0)



def sweep_period_us(timestamps_us) -> int:
    """Median spacing of consecutive sweeps' first-azimuth times (µs); 250 ms (4 Hz) for fewer
    than two sweeps or no spacing."""
    if len(timestamps_us) < 2:
        return 250_000
    return int(np.median(np.diff(np.asarray(timestamps_us, dtype=np.int64)))) or 250_000


def cycled(scan, i: int, distinct: int, period_us: int):
    """Sweep ``i`` of a stream that cycles ``distinct`` sweeps (``scan`` is sweep ``i % distinct``):
    its timestamps moved on by the laps completed, so the stream stays continuous."""
    from dataclasses import replace

    lap = i // distinct
    return replace(scan, timestamps_us=scan.timestamps_us + lap * distinct * period_us) if lap else scan

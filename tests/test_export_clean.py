"""Shipped ONNX files carry no build-machine paths: the exporter's per-node metadata is stripped."""
from __future__ import annotations

import math
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")
onnx = pytest.importorskip("onnx")

from test_fast_search import tiny_profile  # noqa: E402

from radar_odom_export.fast_search import FastSearchSettings  # noqa: E402
from radar_odom_export.model import MaskedCorrelator  # noqa: E402
from radar_odom_export.onnx_export import export_fast  # noqa: E402

pytestmark = pytest.mark.torch


@pytest.mark.slow
def test_exported_file_has_no_node_metadata_and_no_source_paths(tmp_path):
    torch.manual_seed(0)
    p = tiny_profile(width_px=64, max_translation_m=6.0, rotation_range_rad=math.radians(6),
                     rotation_step_rad=math.radians(1))
    report = export_fast(MaskedCorrelator(p, masking="learned").eval(), tmp_path / "m.onnx",
                         FastSearchSettings(coarse_factor=2, coarse_stride=2, band_half_width=1), verify=False)
    proto = onnx.load(str(report.path))
    assert all(len(n.metadata_props) == 0 for n in proto.graph.node)
    raw = Path(report.path).read_bytes()
    src = str(Path(__file__).resolve().parents[1]).encode()
    assert src not in raw and b"stack_trace" not in raw
    assert any(m.key == "radar_odom.profile" for m in proto.metadata_props)  # ours stay

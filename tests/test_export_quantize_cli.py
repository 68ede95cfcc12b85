"""`radar-odom export … --quantize static [--quantize-real SEQ]` (issue 52, item 2): the command line's
choices are the quantiser's, its real recordings reach the calibration, and a real recording without
--quantize is refused in one line before any work. The quantisation itself: tests/test_quantize.py."""
from __future__ import annotations

import argparse
from types import SimpleNamespace

import pytest

pytest.importorskip("torch")

from conftest import one_error_line  # noqa: E402

from radar_odom.commands.cli import main  # noqa: E402
from radar_odom_export import quantize  # noqa: E402
from radar_odom_export.commands import export as export_cmd  # noqa: E402


def _export_parser():
    parser = argparse.ArgumentParser()
    export_cmd.register(parser.add_subparsers(dest="command"))
    return parser


def test_the_command_offers_the_quantisers_schemes():
    action = next(a for a in _export_parser()._subparsers._group_actions[0].choices["export"]._actions
                  if a.dest == "quantize")
    assert tuple(action.choices) == quantize.QUANTIZE_CHOICES and action.choices[0] == "static"


def test_real_calibration_without_quantize_is_refused_before_any_work(tmp_path, capsys):
    assert main(["export", "cart-0.4", "-o", str(tmp_path / "m.onnx"), "--quantize-real", str(tmp_path)]) == 1
    line = one_error_line(capsys, "export")
    assert "--quantize-real" in line and "--quantize static" in line
    assert list(tmp_path.iterdir()) == []


def test_quantize_static_passes_its_real_recordings_to_the_calibration(tmp_path, monkeypatch, capsys):
    from radar_odom_export.checkpoint import save_checkpoint
    from radar_odom_export.model import MaskedCorrelator

    from fixtures import SMALL

    seen = {}

    def fake_export_quantized(ckpt, out, **kw):
        seen.update(kw, out=out)
        report = SimpleNamespace(path=out, summary=lambda: f"wrote {out}")
        return report, report

    monkeypatch.setattr(quantize, "export_quantized", fake_export_quantized)
    ckpt = save_checkpoint(tmp_path / "m.pt", MaskedCorrelator(SMALL, masking="learned").eval(), "learned", train={})
    rec = tmp_path / "drive"
    rec.mkdir()
    out = tmp_path / "m-static.onnx"
    assert main(["export", str(ckpt), "-o", str(out), "--search", "fast", "--no-calibrate",
                 "--quantize", "static", "--quantize-real", str(rec), "--quantize-real", str(rec)]) == 0
    assert seen["quantize"] == "static" and [str(p) for p in seen["real"]] == [str(rec), str(rec)]
    assert seen["out"] == out and seen["exclude"] == quantize.DEFAULT_FLOAT_CONVS

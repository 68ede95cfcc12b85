"""`radar-odom train` under torchrun: two processes, DistributedDataParallel on gloo (CPU)."""
import json
import os
import subprocess
import sys
from dataclasses import asdict

import pytest

torch = pytest.importorskip("torch")

from radar_odom.profiles import GridProfile  # noqa: E402

pytestmark = [pytest.mark.torch, pytest.mark.slow]

TINY = GridProfile("tiny", resolution_m=1.6, width_px=64, max_translation_m=4, rotation_range_rad=0.05,
                   rotation_step_rad=0.025, unet_base_channels=4, unet_depth=3)


def test_train_runs_on_two_ranks_and_writes_one_loadable_checkpoint(tmp_path):
    from radar_odom_export.checkpoint import load_checkpoint
    from radar_odom_export.train import log_path

    prof = tmp_path / "tiny.json"
    prof.write_text(json.dumps(asdict(TINY)))
    out = tmp_path / "ddp.pt"
    env = {**os.environ, "RADAR_ODOM_CACHE": str(tmp_path / "cache"), "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
           "-m", "radar_odom", "train", "-o", str(out), "--profile", str(prof),
           "--sim-seeds", "1000", "--val-seeds", "2000", "--scenarios", "urban", "--frames", "9",
           "--epochs", "2", "--batch", "2", "--threads", "1", "--workers", "1"]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]

    model, meta = load_checkpoint(out)
    rec = meta["train"]
    assert rec["world_size"] == 2
    # 8 pairs, 4 per rank, batch 2 -> 2 steps per epoch on each rank, 2 epochs
    assert rec["rank_steps"] == [4, 4]
    assert rec["ranks_in_sync"] is True
    assert meta["profile"] == TINY
    log = json.loads(log_path(out).read_text())
    assert [e["epoch"] for e in log["epochs"]] == [1, 2]
    # only rank 0 writes: one checkpoint, one state file, no per-rank copies
    written = sorted(p.name for p in tmp_path.iterdir() if p.suffix in (".pt", ".json", ".png"))
    assert written == ["ddp.log.json", "ddp.loss.png", "ddp.pt", "ddp.state.pt", "tiny.json"]
    assert proc.stdout.count("wrote ") == 1

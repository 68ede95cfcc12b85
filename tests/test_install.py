"""`pip install radar-odom` without extras, in a fresh virtual environment, runs a shipped model.

The runtime promise of the design card: numpy, onnxruntime and OpenCV are enough. The project is
installed from this checkout (not editable, so the wheel's package data is what is tested) into
a venv that cannot see this interpreter's packages; torch must not be importable there at all.
"""
import os
import re
import subprocess
import sys
import venv
from pathlib import Path

import pytest
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = """
import sys
import numpy as np
import radar_odom
from radar_odom import RadarOdometer, pretrained, pretrained_names
from radar_odom.sim import simulate_drive

try:
    import torch  # noqa: F401
except ImportError:
    pass
else:
    raise SystemExit("torch is importable in the bare venv: the test proves nothing")
names = pretrained_names()
assert "cart-0.4" in names, names
odo = RadarOdometer(pretrained("cart-0.4"))
estimates = [odo.step(frame.scan) for frame in simulate_drive(9005, 3)]
assert estimates[0] is None and all(e is not None for e in estimates[1:])
assert all(np.all(np.isfinite(e.pose)) and np.all(np.isfinite(e.covariance)) for e in estimates[1:])
assert not [m for m in sys.modules if m.split(".")[0] == "torch"]
print("ok", names, estimates[-1].pose)
"""


@pytest.mark.slow
def test_bare_install_runs_the_shipped_model_without_torch(tmp_path):
    if not (ROOT / "sdk" / "radar_odom" / "models" / "cart-0.4.onnx").is_file():
        pytest.fail("sdk/radar_odom/models/cart-0.4.onnx is missing: the package must ship it")
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True, system_site_packages=False).create(env_dir)
    python = env_dir / ("Scripts" if os.name == "nt" else "bin") / "python"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    pip = subprocess.run([str(python), "-m", "pip", "install", "-q", "--disable-pip-version-check", str(ROOT)],
                         capture_output=True, text=True, env=env, timeout=900)
    assert pip.returncode == 0, pip.stdout[-2000:] + pip.stderr[-4000:]
    out = subprocess.run([str(python), "-c", SCRIPT], capture_output=True, text=True, env=env,
                         cwd=tmp_path, timeout=300)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-4000:]
    assert out.stdout.startswith("ok")


def test_ci_floors_pin_each_declared_minimum():
    """.ci/floors.txt (what the floors job installs) is exactly the `>=` floor of every runtime dependency."""
    text = (ROOT / "pyproject.toml").read_text()
    block = re.search(r"^dependencies = \[(.*?)^\]", text, re.S | re.M).group(1)
    declared = dict(re.findall(r'"([A-Za-z0-9_.-]+)>=([^",;<]+)"', block))
    assert len(declared) == len(re.findall(r'"[^"]+"', block)), f"every runtime dependency has a >= floor: {block}"
    pins = dict(line.split("==") for line in (ROOT / ".ci" / "floors.txt").read_text().splitlines()
                if line.strip() and not line.startswith("#"))
    assert set(pins) == set(declared)
    for name, floor in declared.items():  # 1.19 and 1.19.0 are one version
        assert Version(pins[name]) == Version(floor), (name, pins[name], floor)

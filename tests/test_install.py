"""Packaging facts the floors CI job relies on.

The bare install itself (`pip install .` without extras, in a fresh venv where torch is not
importable, at the declared minimum versions, running the runtime tests on the shipped models)
is the second job of `.ci/run`; here: its pins are the declared floors.
"""
import re
from pathlib import Path

from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]


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

"""Every python block of README.md runs as written, in a folder where
``radar-odom simulate seq --frames 6`` was run (what the README promises a new user)."""
import importlib.util
import os
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BLOCK = re.compile(r"```python\n(.*?)```", re.S)


def python_blocks() -> list[str]:
    return BLOCK.findall((ROOT / "README.md").read_text())


def test_the_readme_has_python_blocks_and_stays_short():
    assert len(python_blocks()) >= 2
    assert len((ROOT / "README.md").read_text().splitlines()) <= 300


@pytest.fixture(scope="module")
def simulated_folder(tmp_path_factory):
    from radar_odom.sim.writer import write_drive

    folder = tmp_path_factory.mktemp("readme")
    write_drive(folder / "seq", seed=0, frames=6)  # what `radar-odom simulate seq --frames 6` writes
    return folder


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(python_blocks())))
def test_a_readme_python_block_runs_as_written(index, simulated_folder, monkeypatch, capsys):
    code = python_blocks()[index]
    if "rosbags" in code and importlib.util.find_spec("rosbags") is None:
        pytest.skip("this block writes a ROS bag: needs rosbags (the ros or dev extra)")
    monkeypatch.chdir(simulated_folder)
    exec(compile(code, f"README.md python block {index + 1}", "exec"), {"__name__": "__readme__"})
    assert os.getcwd() == str(simulated_folder)

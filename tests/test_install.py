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


def test_package_metadata_names_authors_urls_classifiers_and_the_ros_extra():
    """`pip show radar-odom` has an author and a URL; PyPI gets classifiers; the ros extra exists and
    the dev extra installs rosbags (the main CI job runs the bag tests)."""
    text = (ROOT / "pyproject.toml").read_text()
    assert re.search(r"^authors = \[\{ name = \"[^\"]+\"", text, re.M)
    urls = re.search(r"^\[project\.urls\]\n(.*?)\n\n", text, re.S | re.M).group(1)
    assert re.search(r'= "https://', urls)
    classifiers = re.search(r"^classifiers = \[(.*?)^\]", text, re.S | re.M).group(1)
    assert "Programming Language :: Python :: 3.10" in classifiers and "License" not in classifiers  # PEP 639
    assert re.search(r'^ros = \["rosbags>=[0-9.]+"\]', text, re.M)
    dev = re.search(r"^dev = \[(.*?)\]", text, re.M).group(1)
    assert '"rosbags>=' in dev


def test_the_torch_install_line_names_the_cpu_wheel_index_everywhere():
    """README's test command and the missing-torch hint of export/train/calibrate install the CPU
    build explicitly (not by this machine's pip configuration), and the hint works in a checkout."""
    from radar_odom.errors import TORCH_CPU_INDEX, TORCH_VERSION, MissingExtraError

    readme = (ROOT / "README.md").read_text()
    assert f"pip install torch=={TORCH_VERSION} --extra-index-url {TORCH_CPU_INDEX}" in readme
    ci = (ROOT / ".ci" / "run").read_text()
    assert f"torch=={TORCH_VERSION}" in ci
    text = str(MissingExtraError("torch", "export"))
    assert TORCH_CPU_INDEX in text and "pip install -e ./export" in text and "pip install radar-odom-export" in text
    assert f"torch=={TORCH_VERSION}" in text
    assert 'pip install -e ".[ros]"' in str(MissingExtraError("rosbags", "ros"))


def test_readme_documents_the_real_data_variable():
    from conftest import REAL_DATA_ENV

    assert REAL_DATA_ENV in (ROOT / "README.md").read_text()

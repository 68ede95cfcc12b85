"""Two distributions from one repository (issue 52, item 3).

``radar-odom`` (pyproject.toml, sdk/): the runtime, numpy + onnxruntime + OpenCV and the shipped ONNX files,
no torch code and no checkpoints. ``radar-odom-export`` (export/pyproject.toml): the torch side, which adds
`radar-odom export|train|calibrate|adapt` through the ``radar_odom.commands`` entry points. Here: both wheels
are built (offline, no build isolation: setuptools is in the dev extra) and their contents checked, and the
command line with and without the torch side. `.ci/run`'s runtime-wheel job installs the runtime wheel in a
fresh venv and runs README.md's API block.
"""
from __future__ import annotations

import ast
import importlib.util
import re
import subprocess
import sys
import zipfile
from importlib import metadata
from pathlib import Path

import pytest

from radar_odom.commands import ENTRY_POINT_GROUP, TORCH_COMMANDS
from radar_odom.commands.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
TORCH_SIDE = ("torch", "radar_odom_export")


def imported_roots(source: str) -> set[str]:
    """Top-level package names a Python source imports anywhere (function-level imports included)."""
    roots = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            roots |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            roots.add(node.module.split(".")[0])
    return roots


def test_imported_roots_sees_lazy_imports():
    src = "import numpy as np\ndef f():\n    import torch.nn\n    from radar_odom_export.train import x\n"
    assert imported_roots(src) == {"numpy", "torch", "radar_odom_export"}


def test_runtime_sources_never_import_the_torch_side():
    """Not even lazily: every runtime file, function-level imports included (the 16 lazy imports of issue 52 are
    gone; `latency.models` starts ``python -m radar_odom_export.untrained`` as a child process, by name)."""
    wrong = {str(f.relative_to(ROOT)): sorted(imported_roots(f.read_text()) & set(TORCH_SIDE))
             for f in (ROOT / "sdk" / "radar_odom").rglob("*.py")}
    assert {k: v for k, v in wrong.items() if v} == {}


def _build_wheel(project: Path, out: Path) -> Path:
    pytest.importorskip("setuptools", minversion="77", reason="building wheels offline needs setuptools >= 77 (dev)")
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                           "-w", str(out), str(project)], capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (wheel,) = out.glob("*.whl")
    return wheel


@pytest.fixture(scope="module")
def runtime_wheel(tmp_path_factory) -> Path:
    return _build_wheel(ROOT, tmp_path_factory.mktemp("runtime-wheel"))


@pytest.fixture(scope="module")
def export_wheel(tmp_path_factory) -> Path:
    return _build_wheel(ROOT / "export", tmp_path_factory.mktemp("export-wheel"))


def _entry_points(zf: zipfile.ZipFile) -> str:
    (name,) = [n for n in zf.namelist() if n.endswith(".dist-info/entry_points.txt")]
    return zf.read(name).decode()


@pytest.mark.slow
def test_runtime_wheel_has_no_torch_code_and_no_checkpoints(runtime_wheel):
    assert runtime_wheel.name.startswith("radar_odom-")
    with zipfile.ZipFile(runtime_wheel) as zf:
        names = zf.namelist()
        assert not [n for n in names if n.endswith((".pt", ".pth"))]
        assert not [n for n in names if n.startswith("radar_odom_export")]
        assert {"radar_odom/models/cart-0.4.onnx", "radar_odom/models/registry.json"} <= set(names)
        torch_users = [n for n in names if n.endswith(".py")
                       and imported_roots(zf.read(n).decode()) & set(TORCH_SIDE)]
        assert torch_users == []
        assert "radar-odom = radar_odom.commands.cli:main" in _entry_points(zf)
        assert f"[{ENTRY_POINT_GROUP}]" not in _entry_points(zf)  # the torch side's commands are not the runtime's
        (meta,) = [n for n in names if n.endswith(".dist-info/METADATA")]
        requires = re.findall(r"^Requires-Dist: ([A-Za-z0-9_.-]+)(.*)$", zf.read(meta).decode(), re.M)
    base = {name for name, rest in requires if "extra ==" not in rest}
    assert base == {"numpy", "onnxruntime", "opencv-python-headless"}


@pytest.mark.slow
def test_export_wheel_carries_the_checkpoints_and_registers_the_commands(export_wheel):
    assert export_wheel.name.startswith("radar_odom_export-")
    with zipfile.ZipFile(export_wheel) as zf:
        names = set(zf.namelist())
        ckpts = {p.name for p in (ROOT / "export" / "radar_odom_export" / "checkpoints").glob("*.pt")}
        assert ckpts and {f"radar_odom_export/checkpoints/{c}" for c in ckpts} <= names
        assert {f"radar_odom_export/commands/{c}.py" for c in TORCH_COMMANDS} <= names
        assert not [n for n in names if n.startswith("radar_odom/")]  # the runtime is the other wheel
        eps = _entry_points(zf)
        (meta,) = [n for n in names if n.endswith(".dist-info/METADATA")]
        text = zf.read(meta).decode()
    assert f"[{ENTRY_POINT_GROUP}]" in eps
    for name in TORCH_COMMANDS:
        assert f"{name} = radar_odom_export.commands.{name}:register" in eps
    version = re.search(r'^version = "([^"]+)"', (ROOT / "pyproject.toml").read_text(), re.M).group(1)
    assert f"Requires-Dist: radar-odom=={version}" in text  # one release: the same version of the runtime
    assert re.search(r"^Requires-Dist: torch", text, re.M)


def test_both_pyprojects_carry_one_version():
    ver = [re.search(r'^version = "([^"]+)"', p.read_text(), re.M).group(1)
           for p in (ROOT / "pyproject.toml", ROOT / "export" / "pyproject.toml")]
    assert ver[0] == ver[1]
    assert f'"radar-odom=={ver[0]}"' in (ROOT / "export" / "pyproject.toml").read_text()


# --------------------------------------------------------------------------- the command line
def _flat(text: str) -> str:
    return "".join(text.split())  # argparse wraps help lines at the terminal's width, hyphens included


def _subparser(parser, name):
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    return sub.choices[name]


def test_without_the_torch_side_its_commands_are_listed_and_say_how_to_install(monkeypatch, capsys):
    import radar_odom.commands.cli as cli

    monkeypatch.setattr(cli, "plugin_commands", lambda: {})
    parser = build_parser()
    listing = _flat(parser.format_help())
    for name in TORCH_COMMANDS:
        assert _flat(f"{TORCH_COMMANDS[name]} (needs radar-odom-export: not installed)") in listing
    assert main(["train", "-o", "m.pt", "--minutes", "3"]) == 1  # options it cannot know: still the one line
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("radar-odom train: error: `radar-odom train` is part of the torch")
    assert "pip install radar-odom-export" in err and "pip install -e ./export" in err and "--extra-index-url" in err
    assert main(["export"]) == 1 and "radar-odom-export" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["calibrate", "--help"])
    assert exc.value.code == 0 and "pip install -e ./export" in capsys.readouterr().out


def test_installed_distributions_add_commands_through_the_entry_point_group(tmp_path, monkeypatch, capsys):
    """A distribution's ``radar_odom.commands`` entry point replaces the stand-in (and a new name is added)."""
    (tmp_path / "fake_side.py").write_text(
        "def register(sub):\n"
        "    p = sub.add_parser('train', help='fake train')\n"
        "    p.add_argument('-o')\n"
        "    p.set_defaults(func=lambda a: print('trained', a.o) or 0)\n"
        "def register_extra(sub):\n"
        "    sub.add_parser('hello', help='a third party command').set_defaults(func=lambda a: 0)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    eps = {"train": metadata.EntryPoint("train", "fake_side:register", ENTRY_POINT_GROUP),
           "hello": metadata.EntryPoint("hello", "fake_side:register_extra", ENTRY_POINT_GROUP)}
    import radar_odom.commands.cli as cli

    monkeypatch.setattr(cli, "plugin_commands", lambda: eps)
    assert main(["train", "-o", "x.pt"]) == 0 and capsys.readouterr().out == "trained x.pt\n"
    assert main(["hello"]) == 0
    listing = _flat(build_parser().format_help())
    assert "faketrain" in listing and "athirdpartycommand" in listing and "train(needs" not in listing
    assert _flat("export a trained checkpoint to one ONNX graph (needs radar-odom-export: not installed)") in listing


@pytest.mark.torch
def test_the_installed_torch_side_registers_its_commands():
    if importlib.util.find_spec("radar_odom_export") is None:
        pytest.skip("the torch side (radar-odom-export, needs torch) is not installed")
    names = {ep.name for ep in metadata.entry_points(group=ENTRY_POINT_GROUP)}
    assert set(TORCH_COMMANDS) <= names
    assert "needsradar-odom-export" not in _flat(build_parser().format_help())
    assert "--resume" in _subparser(build_parser(), "train").format_help()

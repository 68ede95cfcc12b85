import subprocess
import sys


def test_import_radar_odom_never_imports_torch():
    code = (
        "import sys, radar_odom\n"
        "from radar_odom import *\n"
        "import radar_odom.cli\n"
        "radar_odom.cli.build_parser()\n"
        "bad = [m for m in sys.modules if m == 'torch' or m.startswith('torch.')]\n"
        "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_cli_help_lists_commands():
    out = subprocess.run(
        [sys.executable, "-m", "radar_odom", "--help"], capture_output=True, text=True, check=True
    ).stdout
    assert "radar-odom" in out


def test_pretrained_is_the_function_and_no_module_shadows_it():
    """`radar_odom.pretrained` is the public function; the module defining it has another name
    (`model_zoo`), so importing any submodule first cannot rebind the package attribute."""
    code = (
        "import importlib, pkgutil, radar_odom\n"
        "names = [m.name for m in pkgutil.iter_modules(radar_odom.__path__)]\n"
        "assert 'pretrained' not in names, names\n"
        "import radar_odom.model_zoo, radar_odom.odometer, radar_odom.demo\n"
        "assert callable(radar_odom.pretrained), radar_odom.pretrained\n"
        "from radar_odom import pretrained\n"
        "assert callable(pretrained)\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)

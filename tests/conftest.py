"""Shared fixtures: where the real sweeps are, the committed tiny models, the torch-free check.

The real Navtech sweeps (Oxford Radar RobotCar, RADIATE) are under non-commercial licences, so
they are never copied into the repository: tests read them from ``../shared/data/real/``
beside the checkout (CI has that path), or from ``$RADAR_ODOM_REAL_DATA``. Tests that need them
are marked ``real`` and are skipped, with the path in the reason, where the folder is absent.

The runtime tests read tiny ONNX models committed in ``tests/fixtures/`` (made by
``python tests/fixtures/make_models.py``; ``test_fixture_models`` checks, where torch is
installed, that a fresh export still matches them), so they run where torch is absent.

``RADAR_ODOM_REQUIRE_TORCHLESS=1`` (the floors job of ``.ci/run``, a venv without torch): a test
skipped for want of torch then fails, unless it is marked ``torch`` or its whole module is
export-side (skipped at import by a module-level ``pytest.importorskip("torch")``). A runtime
test that needs a model takes a committed fixture instead of exporting one.
"""
import atexit
import importlib.util
import os
import shutil
import tempfile
from pathlib import Path

import pytest

REAL_DATA_ENV = "RADAR_ODOM_REAL_DATA"
DEFAULT_REAL_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"
TORCHLESS_ENV = "RADAR_ODOM_REQUIRE_TORCHLESS"
FIXTURE_DIR = Path(__file__).resolve().parent / "fixtures"

# the model registry's local folder (radar_odom.model_registry: $RADAR_ODOM_HOME/models, default ~/.radar-odom):
# an empty one of this process's own, so that a tester's own registered models never enter the suite's
# pretrained_names(); tests of the local registry point RADAR_ODOM_HOME at their tmp_path
os.environ["RADAR_ODOM_HOME"] = tempfile.mkdtemp(prefix="radar-odom-home-")
atexit.register(shutil.rmtree, os.environ["RADAR_ODOM_HOME"], True)

# runtime test files that still export their model with torch; the torch-free job reports their
# skips but does not fail on them. Empty this as each one moves to a committed fixture.
PENDING_TORCHLESS: dict[str, str] = {}  # test files not yet torch-free (path -> what is left to do)


def real_data_path() -> Path:
    """The real-sweep folder: ``$RADAR_ODOM_REAL_DATA`` if set, else ``<checkout>/../shared/data/real``."""
    env = os.environ.get(REAL_DATA_ENV)
    return Path(env).expanduser() if env else DEFAULT_REAL_DATA


@pytest.fixture(scope="session")
def real_data_dir() -> Path:
    """Path of the real sweeps; skips the test (saying where it looked) when the folder is absent."""
    path = real_data_path()
    if not path.is_dir():
        pytest.skip(
            f"real sweeps not found at {path} (set {REAL_DATA_ENV}, or place them at "
            "../shared/data/real beside the checkout)"
        )
    return path


# --------------------------------------------------------------------------- committed models
def fixture_file(name: str) -> Path:
    """``tests/fixtures/<name>``; a missing file fails the test (it is committed, never skipped)."""
    path = FIXTURE_DIR / name
    if not path.is_file():
        pytest.fail(f"{path} is missing: run `python tests/fixtures/make_models.py` and commit it")
    return path


@pytest.fixture(scope="session")
def tiny_model() -> Path:
    """Untrained raw-scan model, `fixtures.TINY` grid, stream form, Cartesian, for `fixtures.GEOM`."""
    return fixture_file("tiny-raw.onnx")


@pytest.fixture(scope="session")
def tiny_polar_model() -> Path:
    """As `tiny_model` with polar input, built for `fixtures.GEOM` only."""
    return fixture_file("tiny-polar-raw.onnx")


@pytest.fixture(scope="session")
def tiny_pair_model() -> Path:
    """As `tiny_model` in the pair form."""
    return fixture_file("tiny-pair-raw.onnx")


@pytest.fixture(scope="session")
def cli_model() -> Path:
    """Untrained raw-scan model, `fixtures.CLI` grid, stream form, for the simulator's default sweeps."""
    return fixture_file("cli-raw.onnx")


@pytest.fixture(scope="session")
def fast_learned_model() -> Path:
    """`fixtures.SMALL` grid, a seeded untrained U-Net masker and the coarse-to-fine yaw search."""
    return fixture_file("small-fast-learned.onnx")


@pytest.fixture(scope="session")
def sequence_model() -> Path:
    """`fast_learned_model`'s model (same seeded weights) in the sequence form (`radar_odom.odometry.batch`)."""
    return fixture_file("small-fast-seq.onnx")


@pytest.fixture(scope="session")
def foreign_model() -> Path:
    """An ONNX file (Identity graph) that is not a radar-odom model."""
    return fixture_file("foreign.onnx")


@pytest.fixture(scope="session")
def sweep_form_models(tmp_path_factory) -> dict:
    """{"cart-0.4": path, "cart-0.8": path}: the shipped stream graphs in the sweep form (docs/sweep-form.md),
    wrapped with onnx (no torch); skips where onnx is absent (the torch-free job: the runtime alone)."""
    pytest.importorskip("onnx", reason="onnx (the export extra) builds the sweep form")
    import onnx

    import radar_odom
    from radar_odom_export.sweep_form import wrap_stream_model

    out = tmp_path_factory.mktemp("sweep-form")
    paths = {}
    for name in ("cart-0.4", "cart-0.8"):
        paths[name] = out / f"{name}-sweep.onnx"
        onnx.save(wrap_stream_model(radar_odom.pretrained(name)), str(paths[name]))
    return paths


# --------------------------------------------------------------------------- the torch-free job


def one_error_line(capsys, command: str) -> str:
    """stderr of a refused command: exactly one line, the CLI's own error line (no traceback); returned."""
    err = capsys.readouterr().err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert "Traceback" not in err, err
    assert len(lines) == 1, err
    assert lines[0].startswith(f"radar-odom {command}: error: "), err
    return lines[0]


def _torchless_required() -> bool:
    return os.environ.get(TORCHLESS_ENV, "") not in ("", "0")


def pytest_configure(config):
    if _torchless_required() and importlib.util.find_spec("torch") is not None:
        raise pytest.UsageError(f"{TORCHLESS_ENV} is set but torch is importable: the torch-free run proves nothing")


def _skip_reason(report) -> str:
    longrepr = report.longrepr
    if isinstance(longrepr, tuple) and len(longrepr) == 3:
        return str(longrepr[2])
    return str(longrepr)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if not (_torchless_required() and report.skipped and "torch" in _skip_reason(report)):
        return
    if item.get_closest_marker("torch") is not None or hasattr(report, "wasxfail"):
        return
    path = item.nodeid.split("::")[0]
    if path in PENDING_TORCHLESS:
        return
    report.outcome = "failed"
    report.longrepr = (
        f"{item.nodeid} was skipped for want of torch ({_skip_reason(report)}) in the torch-free run "
        f"({TORCHLESS_ENV}=1): a runtime test reads a committed model (tests/fixtures, see conftest.py); "
        "a test that really needs torch is marked @pytest.mark.torch"
    )


def pytest_terminal_summary(terminalreporter):
    if _torchless_required():
        terminalreporter.write_line(
            f"{TORCHLESS_ENV}=1: skips for want of torch fail, except tests marked torch, export-side "
            f"modules and the pending files {sorted(PENDING_TORCHLESS) or 'none'}")

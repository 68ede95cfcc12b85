"""The torch-free runtime: RadarOdometer over synthetic sweeps, its faults, pretrained models, threads.

The model is an untrained raw-scan export (mask ≡ 1) on a tiny grid, committed in tests/fixtures
(made by tests/fixtures/make_models.py), so these tests need no torch; sweeps come from a
point-reflector world rendered in polar form at known poses, so the expected relative poses are
known exactly.
"""
import subprocess
import sys

import cv2
import numpy as np
import pytest

from radar_odom.errors import ModelMismatchError, StreamError
from radar_odom.model_zoo import UnknownModelError, pretrained, pretrained_names
from radar_odom.odometry.odometer import Estimate, RadarOdometer, sweep_problem, window_covariance
from radar_odom.onnx_model import count_physical_cores, physical_cores
from radar_odom.profiles import GridProfile
from radar_odom.scan import RadarScan
from radar_odom.se2 import invert, se2, to_xyyaw

from fixtures import GEOM, TINY

# small radar: 120 azimuths, 160 bins of 0.3 m (48 m); tiny grid: 64 px at 1.6 m, ±2 cells, 5 yaws
# 0.05 rad apart (tests/fixtures/make_models.py, which made the committed models these tests read)
PERIOD_US = 250_000
T0_US = 1_547_131_046_000_000


@pytest.fixture(scope="module")
def model_path(tiny_model):
    return tiny_model


@pytest.fixture(scope="module")
def polar_model_path(tiny_polar_model):
    """The tiny raw model with polar input: built for GEOM, and for GEOM only."""
    return tiny_polar_model


def world_points(seed=0, n=160):
    """float[n, 2] reflector positions (m) around the start, none within 6 m of it."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-35, -35], [45, 35], size=(3 * n, 2))
    pts = pts[np.hypot(pts[:, 0], pts[:, 1]) > 6.0]
    return pts[:n]


def render_scan(points, pose, t_us, geom=GEOM, source=None):
    """Polar sweep of point reflectors seen from ``pose`` (sensor frame → world), blurred splats."""
    a_n, b_n, res = geom["num_azimuths"], geom["num_bins"], geom["range_resolution_m"]
    inv = invert(pose)
    q = points @ inv[:2, :2].T + inv[:2, 2]
    r = np.hypot(q[:, 0], q[:, 1])
    phi = np.mod(np.arctan2(q[:, 1], q[:, 0]), 2 * np.pi)
    ai, bi = phi / (2 * np.pi / a_n), r / res - 0.5
    keep = (bi >= 0) & (bi < b_n - 2)
    ai, bi = ai[keep], bi[keep]
    img = np.zeros((a_n, b_n), np.float32)
    a0, b0 = np.floor(ai).astype(int), np.floor(bi).astype(int)
    fa, fb = ai - a0, bi - b0
    for da, wa in ((0, 1 - fa), (1, fa)):  # bilinear splat (azimuth wraps)
        for db, wb in ((0, 1 - fb), (1, fb)):
            np.add.at(img, ((a0 + da) % a_n, b0 + db), wa * wb)
    img = cv2.GaussianBlur(img, (0, 0), sigmaX=6.0, sigmaY=1.5)  # smooth at the 1.6 m grid scale
    img = np.clip(img / max(img.max(), 1e-6) * 1.5, 0, 1).astype(np.float32)
    az = 2 * np.pi * np.arange(a_n) / a_n
    ts = t_us + np.arange(a_n) * (PERIOD_US // a_n)
    return RadarScan.from_arrays(ts, az, img, range_resolution_m=res, source=source or f"synthetic@{t_us}")


def drive(rel_xyyaw, steps, seed=0, geom=GEOM):
    """Sweeps of a constant-motion drive: sweep k+1's pose is sweep k's @ se2(rel)."""
    pts = world_points(seed)
    pose, out = np.eye(3), []
    for k in range(steps):
        out.append(render_scan(pts, pose, T0_US + k * PERIOD_US, geom=geom))
        pose = pose @ se2(*rel_xyyaw)
    return out


def with_power(scan, power=None, valid=None, dt_us=0):
    """A copy of ``scan`` with other power/valid rows or shifted timestamps."""
    return RadarScan.from_arrays(
        scan.timestamps_us + dt_us, scan.azimuths_rad,
        scan.power if power is None else power, valid=scan.valid if valid is None else valid,
        range_resolution_m=scan.range_resolution_m, source="modified",
    )


# --------------------------------------------------------------------------- normal operation
@pytest.mark.parametrize("rel", [(1.6, 0.0, 0.05), (0.0, -1.6, -0.05)])
def test_known_motion_is_recovered_and_chained(model_path, rel):
    odo = RadarOdometer(model_path)
    scans = drive(rel, 4, seed=1)
    assert odo.step(scans[0]) is None
    ests = [odo.step(s) for s in scans[1:]]
    for est in ests:
        assert isinstance(est, Estimate) and not est.flags
        assert est.pose.dtype == np.float64 and est.pose.shape == (3,)
        assert est.covariance.shape == (3, 3) and np.allclose(est.covariance, est.covariance.T)
        # raw correlation on 1.6 m cells: within half a cell and half a yaw step (signs pinned)
        assert abs(est.pose[0] - rel[0]) < 0.8 and abs(est.pose[1] - rel[1]) < 0.8
        assert abs(est.pose[2] - rel[2]) < 0.025
    traj = odo.trajectory
    assert len(traj) == 4 and traj.poses.shape == (4, 3, 3)
    assert np.array_equal(traj.timestamps_us, [s.timestamp_us for s in scans])
    np.testing.assert_allclose(traj.poses[0], np.eye(3))
    chained = np.eye(3)
    for est in ests:
        chained = chained @ se2(*est.pose)
    np.testing.assert_allclose(traj.poses[-1], chained, atol=1e-12)


def test_reset_starts_a_new_trajectory(model_path):
    odo = RadarOdometer(model_path)
    scans = drive((1.6, 0, 0), 3)
    for s in scans:
        odo.step(s)
    odo.reset()
    assert len(odo.trajectory) == 0
    assert odo.step(scans[0]) is None  # an earlier timestamp is fine after reset
    assert len(odo.trajectory) == 1


def test_configures_itself_from_metadata(model_path):
    odo = RadarOdometer(model_path)
    assert odo.profile == TINY
    assert odo.info.sweep_geometry == GEOM
    assert odo.info.form == "stream"
    np.testing.assert_allclose(np.diag(window_covariance(TINY)), [3.2**2 / 3, 3.2**2 / 3, 0.1**2 / 3])


def test_pair_form_model_gives_the_same_estimates(model_path, tiny_pair_model):
    pair = tiny_pair_model
    odo = RadarOdometer(pair)
    assert odo.info.form == "pair" and odo.profile == TINY and odo.info.sweep_geometry == GEOM
    scans = drive((1.6, 0.0, 0.05), 4, seed=2)
    outs = []
    for path in (model_path, pair):
        odo = RadarOdometer(path)
        outs.append([odo.step(s) for s in scans][1:])
    for a, b in zip(*outs):
        np.testing.assert_allclose(a.pose, b.pose, atol=1e-5)
        np.testing.assert_allclose(a.covariance, b.covariance, atol=1e-5, rtol=1e-4)


# --------------------------------------------------------------------------- faults
def test_timestamps_going_backwards_or_repeating_raise(model_path):
    odo = RadarOdometer(model_path)
    a, b = drive((1.6, 0, 0), 2)
    odo.step(b)
    for bad in (a, b):
        with pytest.raises(StreamError, match="reset"):
            odo.step(bad)
    assert len(odo.trajectory) == 1  # a refused sweep leaves no trace


def test_gap_raises_or_resets(model_path):
    a, b = drive((1.6, 0, 0), 2)
    late = with_power(b, dt_us=2_000_000)  # 2.25 s after a
    odo = RadarOdometer(model_path, max_gap_s=1.0)
    odo.step(a)
    with pytest.raises(StreamError, match=r"max_gap_s.*reset\(\)"):
        odo.step(late)
    odo = RadarOdometer(model_path, max_gap_s=1.0, on_gap="reset")
    odo.step(a)
    assert odo.step(late) is None
    assert len(odo.trajectory) == 1 and odo.trajectory.timestamps_us[0] == late.timestamp_us


def test_polar_model_refuses_another_geometry_naming_both(polar_model_path):
    odo = RadarOdometer(polar_model_path)
    assert odo.profile.input_kind == "polar"
    other = dict(GEOM, num_bins=200, range_resolution_m=0.25)
    scan = render_scan(world_points(), np.eye(3), T0_US, geom=other, source="other-radar.png")
    with pytest.raises(ModelMismatchError) as err:
        odo.step(scan)
    msg = str(err.value)
    assert "other-radar.png" in msg and "num_bins: 200" in msg and "num_bins: 160" in msg
    assert "range_resolution_m: 0.25" in msg and "range_resolution_m: 0.3" in msg
    assert len(odo.trajectory) == 0  # a refused sweep leaves no trace
    odo.step(render_scan(world_points(), np.eye(3), T0_US))  # its own geometry is taken
    with pytest.raises(ModelMismatchError, match="num_azimuths: 90"):  # even when longer-ranged
        odo.step(render_scan(world_points(), np.eye(3), T0_US + PERIOD_US,
                             geom=dict(GEOM, num_azimuths=90, num_bins=400)))


# render_scan blurs in cells, so these keep their structure at the 1.6 m grid scale (a much finer
# geometry would render sub-pixel points, which raw correlation cannot rotate-match)
@pytest.mark.parametrize("geom", [
    dict(GEOM, num_azimuths=200, num_bins=200, range_resolution_m=0.25),  # another radar, 50 m
    dict(GEOM, num_azimuths=100, num_bins=110, range_resolution_m=0.5),  # coarser, 55 m
])
def test_cartesian_model_runs_on_another_sweep_geometry(model_path, geom):
    odo = RadarOdometer(model_path)
    assert odo.profile.input_kind == "cartesian" and odo.info.sweep_geometry == GEOM
    rel = (1.6, 0.0, 0.05)
    scans = drive(rel, 3, seed=1, geom=geom)
    assert scans[0].geometry != GEOM and scans[0].max_range_m >= TINY.support_radius_m
    assert odo.step(scans[0]) is None
    for est in [odo.step(s) for s in scans[1:]]:
        assert not est.flags and np.all(np.isfinite(est.pose))
        # polar→Cartesian removed the geometry: the known motion is found as on GEOM sweeps
        assert abs(est.pose[0] - rel[0]) < 0.8 and abs(est.pose[1] - rel[1]) < 0.8
        assert abs(est.pose[2] - rel[2]) < 0.025


def test_cartesian_model_refuses_a_sweep_too_short_for_its_grid(model_path):
    odo = RadarOdometer(model_path)
    need = TINY.support_radius_m  # (63/2 − 2 − 1) × 1.6 = 45.6 m
    assert need == pytest.approx(45.6)
    short = render_scan(world_points(), np.eye(3), T0_US, geom=dict(GEOM, num_bins=120),
                        source="short-radar.png")  # 120 × 0.3 = 36 m
    with pytest.raises(ModelMismatchError) as err:
        odo.step(short)
    msg = str(err.value)
    assert "short-radar.png" in msg and "36.00 m" in msg and "45.60 m" in msg
    assert "smaller grid" in msg
    assert len(odo.trajectory) == 0
    # just long enough is fine: 152 bins × 0.3 = 45.6 m
    ok = render_scan(world_points(), np.eye(3), T0_US, geom=dict(GEOM, num_bins=152))
    assert ok.max_range_m == pytest.approx(need) and odo.step(ok) is None


@pytest.mark.torch
def test_support_radius_is_the_exported_support_disc():
    pytest.importorskip("torch")
    from radar_odom_export.model import support_disc

    for p in (TINY, GridProfile("x", resolution_m=0.4, width_px=256, mask_downsample=2),
              GridProfile("y", resolution_m=0.8, width_px=128)):
        disc = support_disc(p.width_px, p.translation_cells).numpy().astype(bool)
        c = (p.width_px - 1) / 2
        rows = np.arange(p.width_px) - c
        r_px = np.hypot(rows[:, None], rows[None, :])
        assert r_px[disc].max() <= p.support_radius_m / p.resolution_m + 1e-9
        assert r_px[~disc].min() > p.support_radius_m / p.resolution_m
        assert r_px[disc].max() > p.support_radius_m / p.resolution_m - 1.0  # tight, to a pixel


@pytest.mark.parametrize("kind,reason", [("blank", "blank"), ("saturated", "saturated"),
                                         ("invalid", "invalid_rows")])
def test_degenerate_sweep_is_flagged_and_bridged(model_path, kind, reason):
    scans = drive((1.6, 0.0, 0.0), 4, seed=3)
    s2 = scans[2]
    if kind == "blank":
        bad = with_power(s2, power=np.zeros_like(s2.power))
    elif kind == "saturated":
        bad = with_power(s2, power=np.ones_like(s2.power))
    else:  # 90 % of the azimuth rows dropped
        valid = np.zeros(s2.num_azimuths, bool)
        valid[:: 10] = True
        bad = with_power(s2, valid=valid)
    assert sweep_problem(bad) == reason and sweep_problem(s2) is None
    odo = RadarOdometer(model_path)
    ests = [odo.step(s) for s in (scans[0], scans[1], bad, scans[3])]
    e1, e2, e3 = ests[1:]
    assert e2.degenerate and reason in e2.flags
    assert np.all(np.isfinite(e2.pose)) and np.all(np.isfinite(e2.covariance))
    np.testing.assert_allclose(e2.pose, e1.pose)  # constant-velocity prior (equal time steps)
    np.testing.assert_allclose(e2.covariance, window_covariance(TINY))  # knows nothing
    assert e3.flags == {"bridged"}
    assert np.all(np.linalg.eigvalsh(e3.covariance) >= np.linalg.eigvalsh(window_covariance(TINY)).min() - 1e-12)
    traj = odo.trajectory
    assert len(traj) == 4 and np.all(np.isfinite(traj.poses))
    # sweep 3 was matched against sweep 1 (the last good one): its absolute pose follows that match
    direct = RadarOdometer(model_path)
    direct.step(scans[1])
    d = direct.step(scans[3])
    np.testing.assert_allclose(traj.poses[3], traj.poses[1] @ se2(*d.pose), atol=1e-9)
    # and the reported relative pose is re-expressed against the degenerate sweep's prior pose
    np.testing.assert_allclose(e3.pose, to_xyyaw(invert(traj.poses[2]) @ traj.poses[3]), atol=1e-9)


def test_degenerate_first_sweep_then_recovery(model_path):
    scans = drive((1.6, 0.0, 0.0), 3, seed=4)
    odo = RadarOdometer(model_path)
    assert odo.step(with_power(scans[0], power=np.zeros_like(scans[0].power))) is None
    e1 = odo.step(scans[1])
    assert e1.degenerate and "no_reference" in e1.flags  # nothing to match against yet
    e2 = odo.step(scans[2])
    assert not e2.flags  # matched against sweep 1
    assert len(odo.trajectory) == 3


def test_nan_from_the_graph_takes_the_degenerate_path(model_path):
    scans = drive((1.6, 0.0, 0.0), 3, seed=5)
    odo = RadarOdometer(model_path)
    odo.step(scans[0])
    odo.step(scans[1])
    real_run = odo._model.run

    def nan_run(feeds):
        out = real_run(feeds)
        return {k: np.full_like(v, np.nan) for k, v in out.items()}

    odo._model.run = nan_run
    est = odo.step(scans[2])
    assert est.degenerate and "nonfinite" in est.flags
    assert np.all(np.isfinite(est.pose)) and np.all(np.isfinite(est.covariance))
    assert len(odo.trajectory) == 3 and np.all(np.isfinite(odo.trajectory.poses))


# --------------------------------------------------------------------------- torch never imported
def test_runtime_never_imports_torch(model_path):
    code = f"""
import sys, numpy as np
import radar_odom
from radar_odom import RadarOdometer, RadarScan
a, b = {GEOM['num_azimuths']}, {GEOM['num_bins']}
odo = RadarOdometer({str(model_path)!r})
rng = np.random.default_rng(0)
for k in range(3):
    scan = RadarScan.from_arrays({T0_US} + k * {PERIOD_US} + np.arange(a) * 100,
                                 2 * np.pi * np.arange(a) / a, rng.random((a, b)).astype(np.float32) ** 4,
                                 range_resolution_m={GEOM['range_resolution_m']})
    est = odo.step(scan)
assert est is not None and np.all(np.isfinite(est.pose))
bad = sorted(m for m in sys.modules if m == 'torch' or m.startswith('torch.'))
assert not bad, bad
print("ok")
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


# --------------------------------------------------------------------------- pretrained, threads
def test_pretrained_lists_and_resolves(tmp_path):
    assert pretrained_names(tmp_path) == []
    (tmp_path / "cart-0.8.onnx").write_bytes(b"x")
    (tmp_path / "cart-0.4.onnx").write_bytes(b"x")
    (tmp_path / "notes.json").write_text("{}")
    assert pretrained_names(tmp_path) == ["cart-0.4", "cart-0.8"]
    assert pretrained("cart-0.4", tmp_path) == str(tmp_path / "cart-0.4.onnx")
    with pytest.raises(KeyError) as err:
        pretrained("cart-9", tmp_path)
    assert isinstance(err.value, UnknownModelError)
    assert "cart-9" in str(err.value) and "cart-0.4, cart-0.8" in str(err.value)


def test_pretrained_with_nothing_shipped_says_so(tmp_path):
    with pytest.raises(KeyError, match="none"):
        pretrained("cart-0.4", tmp_path / "missing")


def test_physical_cores_counts_smt_siblings_once():
    def block(proc, phys, core):
        return f"processor\t: {proc}\nphysical id\t: {phys}\ncore id\t\t: {core}\nflags\t: fpu\n"

    # 2 sockets × 2 cores × 2 threads
    text = "\n".join(block(p, p // 4, (p // 2) % 2) for p in range(8))
    assert count_physical_cores(text) == 4
    assert count_physical_cores(text, allowed={0, 1}) == 1  # two siblings of one core
    assert count_physical_cores(text, allowed={0, 2, 4}) == 3
    assert count_physical_cores("processor : 0\nmodel name : arm\n") == 0  # no core ids: fall back
    assert 1 <= physical_cores() <= (__import__("os").cpu_count() or 1)


def test_default_threads_are_physical_cores(model_path):
    odo = RadarOdometer(model_path)
    so = odo._model.session.get_session_options()
    assert so.intra_op_num_threads == physical_cores()
    assert RadarOdometer(model_path, threads=1)._model.session.get_session_options().intra_op_num_threads == 1


def test_sessions_do_not_spin_and_the_optimisation_level_is_a_choice(model_path):
    """docs/latency.md: spinning workers held the core the read-ahead thread needed; spinning and
    the other optimisation levels stay available by name."""
    import onnxruntime as ort

    from radar_odom.errors import ConfigError
    from radar_odom.onnx_model import OnnxModel, session_options

    so = RadarOdometer(model_path)._model.session.get_session_options()
    assert so.get_session_config_entry("session.intra_op.allow_spinning") == "0"
    assert so.graph_optimization_level == ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    so = OnnxModel(model_path, spinning=True, optimization="basic").session.get_session_options()
    assert so.get_session_config_entry("session.intra_op.allow_spinning") == "1"
    assert so.graph_optimization_level == ort.GraphOptimizationLevel.ORT_ENABLE_BASIC
    with pytest.raises(ConfigError, match="optimization must be one of"):
        session_options(1, optimization="fast")


def test_sweep_problem_thresholds():
    base = render_scan(world_points(), np.eye(3), T0_US)
    assert sweep_problem(base) is None
    faint = with_power(base, power=np.full_like(base.power, 1.0 / 255))  # below the 2/255 floor
    assert sweep_problem(faint) == "blank"
    half = base.power.copy()
    half[: len(half) // 2 + 2] = 1.0
    assert sweep_problem(with_power(base, power=half)) == "saturated"
    valid = np.ones(base.num_azimuths, bool)
    valid[1: base.num_azimuths - 2: 2] = False  # just over half valid, spread over the turn: usable
    assert valid.mean() > 0.5 and sweep_problem(with_power(base, valid=valid)) is None
    valid = np.ones(base.num_azimuths, bool)
    valid[: base.num_azimuths // 2 - 1] = False  # just over half valid, but over half a turn only
    assert sweep_problem(with_power(base, valid=valid)) == "partial_coverage"


def test_a_foreign_onnx_file_is_refused(foreign_model, tmp_path):
    path = tmp_path / "other.onnx"  # an Identity graph, no radar-odom metadata
    path.write_bytes(foreign_model.read_bytes())
    with pytest.raises(ModelMismatchError, match=r"other.onnx: not a radar-odom model.*radar-odom export"):
        RadarOdometer(path)
    with pytest.raises(FileNotFoundError, match="pretrained_names"):
        RadarOdometer(tmp_path / "missing.onnx")

"""polar→Cartesian: parity with a from-the-maths reference, geometry of point targets, the seam,
non-uniform azimuths, near-range blanking and the map cache."""
import math

import cv2
import numpy as np
import pytest

from radar_odom import polar as P
from radar_odom.errors import ScanFormatError
from radar_odom.scan import RadarScan

TWO_PI = 2 * np.pi
# OpenCV 5 interpolates float remap maps at the exact position; OpenCV 4 first rounds positions to
# 1/32 pixel (INTER_BITS = 5) on each axis: up to 1/64 of a neighbour step per axis, so 1/32 in
# all for power in [0, 1]. The 1e-4 parity holds on OpenCV >= 5 only.
TOL = 1e-4 if int(cv2.__version__.split(".")[0]) >= 5 else 1 / 32 + 1e-4


def reference_cartesian(power, az, range_res, range_off, res_m, width, near_m=0.0, rule="uniform"):
    """Oxford reference geometry written out in numpy, with explicit bilinear sampling."""
    power = np.asarray(power, dtype=np.float64)
    a_rows, n_bins = power.shape
    h = (width / 2 - 0.5) * res_m if width % 2 == 0 else (width // 2) * res_m
    coords = np.linspace(-h, h, width)
    Y, X = np.meshgrid(coords, -coords)
    phi = np.arctan2(Y, X)
    phi = np.where(phi < 0, phi + TWO_PI, phi)
    rho = np.sqrt(X * X + Y * Y)
    u = np.maximum((rho - range_off - range_res / 2) / range_res, 0.0)
    az = np.asarray(az, dtype=np.float64)
    if rule == "uniform":  # the reference kit's formula, +1 for the prepended seam row
        v = (phi - az[0]) / (az[1] - az[0]) + 1
    else:  # locate φ between the two seam-extended azimuths that bracket it
        ext = np.concatenate(([az[-1] - TWO_PI], az, [az[0] + TWO_PI]))
        k = np.searchsorted(ext, phi, side="right") - 1
        v = k + (phi - ext[k]) / (ext[k + 1] - ext[k])
    polar = power.copy()
    polar[:, (range_off + (np.arange(n_bins) + 0.5) * range_res) < near_m] = 0.0
    padded = np.concatenate((polar[-1:], polar, polar[:1]), axis=0)
    x0, y0 = np.floor(u).astype(int), np.floor(v).astype(int)
    fx, fy = u - x0, v - y0

    def at(yy, xx):  # zero outside the padded image (cv2.BORDER_CONSTANT, value 0)
        inside = (yy >= 0) & (yy < padded.shape[0]) & (xx >= 0) & (xx < padded.shape[1])
        return np.where(inside, padded[np.clip(yy, 0, padded.shape[0] - 1), np.clip(xx, 0, padded.shape[1] - 1)], 0.0)

    return (
        at(y0, x0) * (1 - fx) * (1 - fy) + at(y0, x0 + 1) * fx * (1 - fy)
        + at(y0 + 1, x0) * (1 - fx) * fy + at(y0 + 1, x0 + 1) * fx * fy
    )


def make_scan(power, az, range_res=0.0432, range_off=0.0, valid=None, times_us=None):
    """A `RadarScan`; its row times ``times_us`` (int µs), by default 625 µs apart from 0."""
    a = len(az)
    times = np.arange(a, dtype=np.int64) * 625 if times_us is None else np.asarray(times_us, dtype=np.int64)
    return RadarScan.from_arrays(times, az, power, valid=valid, range_resolution_m=range_res, range_offset_m=range_off)


def uniform_az(a, start=0.0):
    return start + np.arange(a) * TWO_PI / a


@pytest.fixture(autouse=True)
def _fresh_cache():
    P.clear_map_cache()
    yield
    P.clear_map_cache()


# ----------------------------------------------------------------------------- parity
@pytest.mark.parametrize("width", [63, 64])
def test_parity_with_reference_on_random_power(width):
    rng = np.random.default_rng(width)
    power = rng.random((400, 600), dtype=np.float32)
    scan = make_scan(power, uniform_az(400))
    # 0.6 m/px × 64 px reaches 26.7 m in the corners, beyond the 25.9 m of 600 bins
    res = 0.6
    got = P.polar_to_cartesian(scan, res, width)
    want = reference_cartesian(scan.power, scan.azimuths_rad, 0.0432, 0.0, res, width)
    assert got.shape == (width, width) and got.dtype == np.float32
    assert np.abs(got - want).max() < TOL
    assert (got[0, 0] == 0.0) and (got[width // 2, width // 2] > 0)  # beyond max range; centre
    out = np.empty((width, width), np.float32)
    assert P.polar_to_cartesian(scan, res, width, out=out) is out
    np.testing.assert_array_equal(out, got)


def test_parity_with_range_offset_and_uint8_array_input():
    rng = np.random.default_rng(3)
    power_u8 = rng.integers(0, 256, (120, 300), dtype=np.uint8)
    az = uniform_az(120, start=0.01)
    got = P.polar_to_cartesian_array(power_u8, az, 0.0596, -0.31, 0.25, 96)
    want = reference_cartesian(power_u8 / 255.0, az.astype(np.float64), 0.0596, -0.31, 0.25, 96)
    assert np.abs(got - want).max() < TOL


# ----------------------------------------------------------------------------- geometry
def _scan_with_target_at_pixel(row, col, width, res_m, az_rule="uniform", a_rows=400, seed=0):
    """A sweep whose single lit cell (power 1) is exactly at Cartesian pixel (row, col).

    The azimuth grid and range offset are shifted so that the pixel's (φ, ρ) is a row angle
    and a bin centre, so the expected image is 1 there by construction of the geometry only.
    """
    c_w = (width - 1) / 2
    x, y = (c_w - row) * res_m, (col - c_w) * res_m
    rho, phi = math.hypot(x, y), math.atan2(y, x) % TWO_PI
    d = TWO_PI / a_rows
    a_idx = int(phi // d)
    az = uniform_az(a_rows, start=phi - a_idx * d)
    if az_rule == "jittered":  # non-uniform spacing, but keep az[a_idx] == φ
        rng = np.random.default_rng(seed)
        az = az + rng.uniform(-0.3, 0.3, a_rows) * d
        az[a_idx] = phi
        az = np.clip(az, 0, TWO_PI - 1e-3)
    range_res = 0.0432
    b_idx = int(rho / range_res - 0.5)
    off = rho - (b_idx + 0.5) * range_res
    power = np.zeros((a_rows, 1000), np.float32)
    power[a_idx, b_idx] = 1.0
    return make_scan(power, az, range_res, off)


@pytest.mark.parametrize("width", [101, 100])
@pytest.mark.parametrize("az_rule", ["uniform", "jittered"])
@pytest.mark.parametrize("quadrant", [(1, 1), (1, -1), (-1, -1), (-1, 1)])
def test_point_target_lands_on_expected_pixel(width, az_rule, quadrant):
    res = 0.4
    c_w = (width - 1) / 2
    x_m, y_m = 9.0 * quadrant[0], 6.0 * quadrant[1]  # +x ahead (up), +y right
    row, col = int(round(c_w - x_m / res)), int(round(c_w + y_m / res))
    scan = _scan_with_target_at_pixel(row, col, width, res, az_rule)
    img = P.polar_to_cartesian(scan, res, width)
    assert np.unravel_index(np.argmax(img), img.shape) == (row, col)
    assert img[row, col] == pytest.approx(1.0, abs=2e-3)
    # above/below and left/right of the target are (x, y) ± one pixel, not the target
    assert img.sum() == pytest.approx(img[row, col], abs=1e-6)


@pytest.mark.parametrize("lit_row", ["first", "last"])
def test_seam_interpolates_between_last_and_first_azimuth(lit_row):
    # few azimuths and az[0] = 0.3·step: a wide seam gap containing both φ → 0⁺ and φ → 2π⁻
    a_rows, width, res = 64, 81, 0.5
    d = TWO_PI / a_rows
    az = uniform_az(a_rows, start=0.3 * d)
    power = np.zeros((a_rows, 450), np.float32)
    power[0 if lit_row == "first" else -1, 100:401] = 1.0
    img = P.polar_to_cartesian(make_scan(power, az), res, width)

    c_w = (width - 1) / 2
    rr, cc = np.mgrid[0:width, 0:width]
    x, y = (c_w - rr) * res, (cc - c_w) * res
    phi = np.arctan2(y, x)  # (-π, π]: continuous across the seam
    u = (np.hypot(x, y) - 0.0216) / 0.0432
    gap_lo, gap_hi = az[-1] - TWO_PI, az[0]
    in_seam = (phi > gap_lo) & (phi < gap_hi) & (u > 101) & (u < 399) & (x > 0)
    w_first = (phi - gap_lo) / (gap_hi - gap_lo)
    expected = w_first if lit_row == "first" else 1 - w_first
    assert (in_seam & (phi >= 0)).any() and (in_seam & (phi < 0)).any()  # both sides of 0/2π
    assert np.abs(img[in_seam] - expected[in_seam]).max() < TOL
    # each side really reads across the seam (a sweep without seam padding would give 0 there)
    assert img[in_seam & (phi >= 0)].max() > 0.2 and img[in_seam & (phi < 0)].max() > 0.2


def test_uniform_azimuths_give_the_reference_formula():
    az = uniform_az(400, start=0.002)
    map_bin, map_row = P.cartesian_sample_maps(az, 3768, 0.0432, 0.0, 0.4, 128)
    h = 63.5 * 0.4
    coords = np.linspace(-h, h, 128)
    Y, X = np.meshgrid(coords, -coords)
    phi = np.arctan2(Y, X)
    phi[phi < 0] += TWO_PI
    v_formula = (phi - az[0]) / (az[1] - az[0]) + 1
    u_formula = np.maximum((np.hypot(X, Y) - 0.0216) / 0.0432, 0)
    assert map_row.dtype == np.float32 and map_row.shape == (128, 128)
    assert np.abs(map_row - v_formula).max() < 1e-4
    assert np.abs(map_bin - u_formula).max() < 1e-3  # float32 positions near bin 2000


def test_non_uniform_azimuths_match_piecewise_reference():
    rng = np.random.default_rng(7)
    a_rows = 400
    az = np.sort(uniform_az(a_rows) + rng.uniform(-0.4, 0.4, a_rows) * TWO_PI / a_rows)
    az = np.clip(az, 0, TWO_PI - 1e-4)
    power = rng.random((a_rows, 500), dtype=np.float32)
    scan = make_scan(power, az)
    got = P.polar_to_cartesian(scan, 0.5, 80)
    want = reference_cartesian(scan.power, scan.azimuths_rad, 0.0432, 0.0, 0.5, 80, rule="piecewise")
    assert np.abs(got - want).max() < TOL
    # and the uniform formula is measurably wrong here, so the test tells the two apart
    naive = reference_cartesian(scan.power, scan.azimuths_rad, 0.0432, 0.0, 0.5, 80, rule="uniform")
    assert np.abs(got - naive).max() > 0.05


def test_near_range_blanking():
    rng = np.random.default_rng(1)
    power = rng.random((400, 800), dtype=np.float32)
    scan = make_scan(power, uniform_az(400), range_off=0.1)
    near = 2.48  # bin 54's centre is at 2.454 m, bin 55's at 2.498 m
    got = P.polar_to_cartesian(scan, 0.2, 90, near_range_m=near)
    want = reference_cartesian(scan.power, scan.azimuths_rad, 0.0432, 0.1, 0.2, 90, near_m=near)
    assert np.abs(got - want).max() < TOL
    plain = P.polar_to_cartesian(scan, 0.2, 90)
    rr, cc = np.mgrid[0:90, 0:90]
    rho = np.hypot(44.5 - rr, cc - 44.5) * 0.2
    assert (got[rho < near - 0.0432] == 0).all() and (plain[rho < near - 0.0432] > 0).any()
    np.testing.assert_array_equal(got[rho > near + 0.0432], plain[rho > near + 0.0432])
    assert P.near_range_bins(near, 0.0432, 0.1, 800) == 55
    assert P.near_range_bins(near, 0.0432, 0.1, 40) == 40 and P.near_range_bins(0.0, 0.0432, 0.1, 800) == 0


def test_invalid_rows_with_junk_azimuths_are_sampled_as_their_neighbours_imply():
    rng = np.random.default_rng(2)
    az = uniform_az(100)
    power = rng.random((100, 300), dtype=np.float32)
    valid = np.ones(100, bool)
    valid[[0, 40, 41, 99]] = False
    junk = az.copy()
    junk[[0, 40, 41, 99]] = [5.0, 0.0, 0.0, 1.0]  # dropped encoder readings
    clean_img = P.polar_to_cartesian(make_scan(power, az, valid=valid), 0.3, 70)
    junk_img = P.polar_to_cartesian(make_scan(power, junk, valid=valid), 0.3, 70)
    assert np.abs(junk_img - clean_img).max() < TOL


# ----------------------------------------------------------------------------- cache
def test_maps_are_built_once_per_geometry(monkeypatch):
    calls = []
    real = P.cartesian_sample_maps
    monkeypatch.setattr(P, "cartesian_sample_maps", lambda *a, **k: calls.append(a) or real(*a, **k))
    rng = np.random.default_rng(0)
    az = uniform_az(400)
    scans = [make_scan(rng.random((400, 300), dtype=np.float32), az) for _ in range(3)]
    imgs = [P.polar_to_cartesian(s, 0.4, 64) for s in scans]
    assert len(calls) == 1 and P.map_cache_info()["builds"] == 1 and P.map_cache_info()["hits"] == 2
    assert not np.array_equal(imgs[0], imgs[1])  # the cached maps do not freeze the output
    P.polar_to_cartesian(scans[0], 0.4, 32)  # another width
    P.polar_to_cartesian(scans[0], 0.2, 64)  # another resolution
    P.polar_to_cartesian(make_scan(scans[0].power, uniform_az(400, 0.001)), 0.4, 64)  # other azimuths
    assert len(calls) == 4
    P.polar_to_cartesian(scans[2], 0.4, 64)
    assert len(calls) == 4


def test_cache_evicts_least_recently_used():
    power = np.zeros((16, 50), np.float32)
    az = uniform_az(16)
    size = P.map_cache_info()["max_entries"]
    for w in range(4, 4 + size + 1):
        P.polar_to_cartesian_array(power, az, 0.0432, 0.0, 0.5, w)
    assert P.map_cache_info()["entries"] == size
    P.polar_to_cartesian_array(power, az, 0.0432, 0.0, 0.5, 4 + size)  # newest: a hit
    assert P.map_cache_info()["builds"] == size + 1
    P.polar_to_cartesian_array(power, az, 0.0432, 0.0, 0.5, 4)  # oldest was evicted
    assert P.map_cache_info()["builds"] == size + 2


def test_moving_maps_are_reused_for_the_same_twist_and_row_times(monkeypatch):
    """De-skew draws both sweeps of a match with one twist: the second drawing reuses the maps, and the image
    is the one freshly built maps draw; another twist, another frame or row times off by more than the
    reuse tolerance build new maps."""
    calls = []
    real = P.moving_sample_maps
    monkeypatch.setattr(P, "moving_sample_maps", lambda *a, **k: calls.append(a) or real(*a, **k))
    rng = np.random.default_rng(1)
    az = uniform_az(400)
    times = 1_000_000 + np.arange(400, dtype=np.int64) * 625  # 0.25 s sweep
    twist = (10.0, 0.2, 0.1)
    a = make_scan(rng.random((400, 300), dtype=np.float32), az, times_us=times)
    b = make_scan(rng.random((400, 300), dtype=np.float32), az, times_us=times + 250_000)  # next sweep, same row times
    img_a = P.polar_to_cartesian(a, 0.4, 64, twist=twist)
    img_b = P.polar_to_cartesian(b, 0.4, 64, twist=twist)
    assert len(calls) == 1 and P.moving_map_cache_info() == {"builds": 1, "hits": 1, "entries": 1, "max_entries": 4}
    P.clear_map_cache()
    np.testing.assert_array_equal(img_b, P.polar_to_cartesian(b, 0.4, 64, twist=twist))  # fresh maps, same image
    assert not np.array_equal(img_a, img_b)
    assert len(calls) == 2
    P.polar_to_cartesian(b, 0.4, 64, twist=(10.0, 0.2, 0.11))  # another twist
    P.polar_to_cartesian(b, 0.4, 64, twist=twist, frame_pose=(1.0, 0.0, 0.0))  # another frame
    assert len(calls) == 4
    # row times jittering by 2 µs move a point 0.02 mm at this twist: reused; 2 ms move it 2 cm: rebuilt
    jitter = np.zeros(400, dtype=np.int64)
    jitter[200:] = 2  # rows from 200 on late (times stay increasing)
    P.polar_to_cartesian(make_scan(b.power, az, times_us=times + jitter), 0.4, 64, twist=twist)
    assert len(calls) == 4
    P.polar_to_cartesian(make_scan(b.power, az, times_us=times + 1000 * jitter), 0.4, 64, twist=twist)
    assert len(calls) == 5


def test_moving_map_reuse_tolerance_is_a_hundredth_of_a_pixel():
    tau = np.linspace(0.0, 0.25, 400)
    res, w = 0.4, 256
    fast = (20.0, 0.0, 0.0)  # 20 m/s: 0.004 m (1 % of 0.4 m) takes 200 µs
    assert P._times_interchangeable(tau, tau + 1.9e-4, fast, res, w)
    assert not P._times_interchangeable(tau, tau + 2.1e-4, fast, res, w)
    # a yaw rate moves the grid's corner: 0.5 rad/s at 72 m (corner of 256 px at 0.4 m) is ~36 m/s
    corner_m = math.sqrt(2.0) * P.half_extent_m(res, w)
    limit_s = 0.01 * res / (0.5 * corner_m)
    assert P._times_interchangeable(tau, tau + 0.9 * limit_s, (0.0, 0.0, 0.5), res, w)
    assert not P._times_interchangeable(tau, tau + 1.1 * limit_s, (0.0, 0.0, 0.5), res, w)
    assert not P._times_interchangeable(tau, tau[:-1], fast, res, w)  # another row count


# ----------------------------------------------------------------------------- bad input
def test_bad_arrays_get_typed_errors():
    az = uniform_az(10)
    with pytest.raises(ScanFormatError, match="azimuths_rad has shape"):
        P.polar_to_cartesian_array(np.zeros((10, 20)), az[:9], 0.0432, 0.0, 0.5, 16)
    with pytest.raises(ScanFormatError, match="increase strictly"):
        P.polar_to_cartesian_array(np.zeros((10, 20)), az[::-1], 0.0432, 0.0, 0.5, 16)
    with pytest.raises(ScanFormatError, match="2-D"):
        P.polar_to_cartesian_array(np.zeros(20), az, 0.0432, 0.0, 0.5, 16)
    with pytest.raises(ValueError, match="width_px"):
        P.polar_to_cartesian_array(np.zeros((10, 20)), az, 0.0432, 0.0, 0.5, 0)
    with pytest.raises(ValueError, match="out must be"):
        P.polar_to_cartesian_array(np.zeros((10, 20)), az, 0.0432, 0.0, 0.5, 16, out=np.zeros((16, 16)))


# ------------------------------------------------------------------ dropped rows
def test_fill_dropped_rows_interpolates_short_runs_in_azimuth_and_wraps_at_the_seam():
    from radar_odom.polar import fill_dropped_rows

    a = 12
    az = np.arange(a) * (2 * np.pi / a) + 0.1
    power = np.stack([np.full(3, k, dtype=np.float32) for k in range(a)])  # row k holds k
    valid = np.ones(a, bool)
    assert fill_dropped_rows(power, az, valid) is power  # nothing to do: the input itself
    valid[[3, 5, 6, 11]] = False
    power[~valid] = 0.0
    out = fill_dropped_rows(power, az, valid)
    assert out[3, 0] == pytest.approx(3.0)               # halfway between rows 2 and 4
    assert out[5, 0] == pytest.approx(5.0)                # a third of the way from row 4 (4) to 7 (7)
    assert out[6, 0] == pytest.approx(6.0)
    assert out[11, 0] == pytest.approx(0.5 * (10 + 0))    # across the seam: rows 10 and 0
    assert np.array_equal(out[valid], power[valid])
    assert power[3, 0] == 0.0  # the caller's array is not touched


def test_fill_dropped_rows_leaves_long_runs_empty():
    from radar_odom.polar import MAX_FILLED_RUN_ROWS, fill_dropped_rows

    a = 20
    az = np.arange(a) * (2 * np.pi / a)
    power = np.ones((a, 2), np.float32)
    valid = np.ones(a, bool)
    valid[4: 4 + MAX_FILLED_RUN_ROWS + 1] = False
    power[~valid] = 0.0
    assert np.array_equal(fill_dropped_rows(power, az, valid), power)

"""RADIATE sweeps: the transposed headerless PNG, Navtech_Polar.txt times, sequences, bad input.

Synthetic RADIATE folders are written into tmp_path; the real sweeps (``real`` marker) are read
from ``../shared/data/real/radiate-fog_6_0`` and ``radiate-2019-02-12-edinburgh`` (never copied
into the repository).
"""
import math

import cv2
import numpy as np
import pytest

from radar_odom import ScanFormatError, SequenceError, load_scan, read_sequence
from radar_odom.io import FORMATS, detect_format
from radar_odom.io.radiate import (
    AGREE,
    DECIMAL,
    NANOSECONDS,
    RADIATE_RANGE_RESOLUTION_M,
    load_radiate,
    parse_frame_times,
    parse_radiate_times,
    read_radiate_times,
    sweep_period_us,
)

A, B = 400, 576
# the first lines of a real Navtech_Polar.txt (RADIATE README): irregular spacing, ns digits
TIMES = ["1574859771.744660272", "1574859771.977525228", "1574859772.213924306",
         "1574859772.452509138", "1574859772.696168000"]
TIMES_US = [1574859771744660, 1574859771977525, 1574859772213924, 1574859772452509, 1574859772696168]


def sweep_image(seed=0, a=A, b=B) -> np.ndarray:
    """uint8[b range rows, a azimuth columns] with every pixel distinct enough to track."""
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, (b, a), dtype=np.uint8)


def write_radiate(root, frames=(1, 2, 3, 4, 5), times=TIMES, images=None, lines=None):
    """SEQ/Navtech_Polar/NNNNNN.png and SEQ/Navtech_Polar.txt; returns {frame: png path}."""
    folder = root / "Navtech_Polar"
    folder.mkdir(parents=True, exist_ok=True)
    paths = {}
    for k, frame in enumerate(frames):
        img = sweep_image(frame) if images is None else images[k]
        paths[frame] = folder / f"{frame:06d}.png"
        assert cv2.imwrite(str(paths[frame]), img)
    if lines is None:
        lines = [f"Frame: {f:06d} Time: {t}" for f, t in zip(frames, times)]
    (root / "Navtech_Polar.txt").write_text("\n".join(lines) + "\n")
    return paths


# ---------------------------------------------------------------- one sweep


def test_sweep_is_transposed_with_uniform_azimuths_and_radiate_range_bins(tmp_path):
    img = sweep_image(7)
    path = write_radiate(tmp_path, images=[img] * 5)[3]
    scan = load_scan(path, "radiate")
    assert scan.power.shape == (A, B) and scan.power.dtype == np.float32
    # row a of the scan is column a of the PNG; bin b is PNG row b
    np.testing.assert_array_equal(scan.power, img.T.astype(np.float32) / np.float32(255))
    assert scan.power[17, 300] == np.float32(img[300, 17]) / np.float32(255)
    np.testing.assert_allclose(scan.azimuths_rad, 2 * math.pi * np.arange(A) / A, atol=1e-6)
    assert scan.azimuths_rad[0] == 0.0 and scan.valid.all() and scan.invalid_rows == ()
    assert scan.range_resolution_m == RADIATE_RANGE_RESOLUTION_M == 0.173611
    assert scan.range_offset_m == 0.0
    assert scan.max_range_m == pytest.approx(100.0, abs=1e-3)  # 576 bins reach 100 m
    assert scan.encoder_counts is None and scan.source == str(path)


def test_times_are_read_exactly_and_spread_over_the_median_frame_spacing(tmp_path):
    paths = write_radiate(tmp_path)
    period = float(np.median(np.diff(TIMES_US)))  # 238 585 µs here
    for k, frame in enumerate((1, 2, 3, 4, 5)):
        scan = load_scan(paths[frame], "radiate")
        assert scan.timestamp_us == TIMES_US[k]  # the frame time is the first azimuth's
        np.testing.assert_array_equal(
            scan.timestamps_us, TIMES_US[k] + np.round(np.arange(A) * period / A).astype(np.int64))
    assert sweep_period_us(parse_radiate_times(paths[1].parent.with_suffix(".txt").read_text(), "t")) == period
    # an explicit period replaces the measured one
    scan = load_scan(paths[2], "radiate", sweep_period_s=0.25)
    assert scan.timestamps_us[-1] - scan.timestamps_us[0] == round(0.25e6 * (A - 1) / A)


def test_seconds_are_parsed_without_float_rounding():
    text = ("Frame: 1 Time: 1574859771.7446605\nFrame: 2 Time: 1574859772.0000004999\n"
            "Frame: 3 Time: 1574859772.25\nFrame: 000004 Time: 1574859773\n")
    assert parse_radiate_times(text, "t") == {
        1: 1574859771744661, 2: 1574859772000000, 3: 1574859772250000, 4: 1574859773000000}


def test_period_uses_neighbouring_frames_only(tmp_path):
    # frames 1, 2, 3 then 7: the 1-s hole before frame 7 is not a sweep period
    times = {1: 0, 2: 250_000, 3: 500_000, 7: 1_500_000}
    assert sweep_period_us(times) == 250_000
    assert sweep_period_us({5: 10}) == 250_000  # nothing to measure: 4 Hz


def test_detect_format_by_folder_name(tmp_path):
    paths = write_radiate(tmp_path)
    assert "radiate" in FORMATS
    assert detect_format(paths[1]) == "radiate"
    assert load_scan(paths[1]).timestamp_us == TIMES_US[0]  # detected, not read as Oxford
    assert detect_format(tmp_path / "radar" / "1.png") == "oxford"
    assert detect_format(tmp_path / "polar" / "1.png") == "mulran"


def test_explicit_timestamp_needs_no_time_file(tmp_path):
    path = tmp_path / "elsewhere" / "sweep.png"
    path.parent.mkdir()
    assert cv2.imwrite(str(path), sweep_image())
    scan = load_radiate(path, timestamp_us=10**15, sweep_period_s=0.25)
    assert scan.timestamp_us == 10**15 and scan.timestamps_us[-1] == 10**15 + 249_375
    with pytest.raises(ScanFormatError, match=r"Navtech_Polar\.txt|elsewhere\.txt"):
        load_radiate(path)  # no time file beside it


# ---------------------------------------------------------------- bad sweeps


def test_transposed_png_is_refused_with_the_fix(tmp_path):
    path = write_radiate(tmp_path, images=[sweep_image(1).T.copy()] + [sweep_image()] * 4)[1]
    with pytest.raises(ScanFormatError) as err:
        load_scan(path, "radiate")
    msg = str(err.value)
    assert str(path) in msg and "400 × 576" in msg and "transpose" in msg


def test_wrong_size_png_is_refused_unless_told(tmp_path):
    small = sweep_image(2, a=100, b=50)
    path = write_radiate(tmp_path, images=[small] * 5)[1]
    with pytest.raises(ScanFormatError, match=r"50 × 100.*576 range rows × 400 azimuth columns"):
        load_scan(path, "radiate")
    scan = load_scan(path, "radiate", num_azimuths=100, num_bins=50)
    assert scan.power.shape == (100, 50)
    np.testing.assert_allclose(scan.azimuths_rad, 2 * math.pi * np.arange(100) / 100, atol=1e-6)


def test_colour_or_16_bit_png_is_refused(tmp_path):
    paths = write_radiate(tmp_path)
    assert cv2.imwrite(str(paths[1]), np.zeros((B, A, 3), np.uint8))
    with pytest.raises(ScanFormatError, match="single-channel"):
        load_scan(paths[1], "radiate")
    assert cv2.imwrite(str(paths[2]), np.zeros((B, A), np.uint16))
    with pytest.raises(ScanFormatError, match="8-bit"):
        load_scan(paths[2], "radiate")


def test_frame_missing_from_the_time_file(tmp_path):
    paths = write_radiate(tmp_path, frames=(1, 2, 3), times=TIMES[:3],
                          lines=[f"Frame: 00000{k} Time: {TIMES[k - 1]}" for k in (1, 2)])
    with pytest.raises(ScanFormatError) as err:
        load_scan(paths[3], "radiate")
    msg = str(err.value)
    assert str(paths[3]) in msg and "frame 3" in msg and "Navtech_Polar.txt" in msg
    assert load_scan(paths[2], "radiate").timestamp_us == TIMES_US[1]  # the others are fine


def test_missing_time_file(tmp_path):
    paths = write_radiate(tmp_path)
    (tmp_path / "Navtech_Polar.txt").unlink()
    with pytest.raises(ScanFormatError, match=r"Navtech_Polar\.txt: no such file.*beside"):
        load_scan(paths[1], "radiate")


@pytest.mark.parametrize("bad_line,match", [
    ("Frame: 000002 Time: 1574859771.97x", r"line 2: cannot read .*Frame: NNNNNN Time: SECONDS"),
    ("Frame 000002 1574859771.977525228", r"line 2: cannot read"),
    ("Frame: 000002 Time:", r"line 2: cannot read"),
    ("Frame: 000001 Time: 1574859771.977525228", r"line 2: frame 1 is listed twice"),
    ("Frame: 000002 Time: 1574859771.744660272", r"line 2: frame 2 at .* is not after frame 1"),
    ("Frame: 000002 Time: 1574859771.000000000", r"line 2: frame 2 at .* is not after frame 1"),
])
def test_garbled_or_non_increasing_time_file(tmp_path, bad_line, match):
    lines = [f"Frame: {k:06d} Time: {t}" for k, t in zip((1, 2, 3), TIMES)]
    lines[1] = bad_line
    paths = write_radiate(tmp_path, frames=(1, 2, 3), lines=lines)
    with pytest.raises(ScanFormatError, match=match) as err:
        load_scan(paths[3], "radiate")
    assert str(tmp_path / "Navtech_Polar.txt") in str(err.value)
    with pytest.raises(SequenceError, match=match):
        read_sequence(tmp_path)


def test_an_edited_time_file_is_read_again(tmp_path):
    paths = write_radiate(tmp_path)
    assert load_scan(paths[1], "radiate").timestamp_us == TIMES_US[0]
    txt = tmp_path / "Navtech_Polar.txt"
    txt.write_text(txt.read_text().replace(TIMES[0], "1574859771.5"))
    assert load_scan(paths[1], "radiate").timestamp_us == 1574859771500000


# ---------------------------------------------------------------- sequences


def test_read_sequence_orders_by_frame_number_and_times_from_the_file(tmp_path):
    frames = (9, 10, 11, 100)
    times = ["1574859771.0", "1574859771.25", "1574859771.5", "1574859771.75"]
    write_radiate(tmp_path, frames=frames[::-1], times=times[::-1])  # written out of order
    seq = read_sequence(tmp_path)
    assert seq.format == "radiate" and len(seq) == 4 and seq.gt_relative is None
    assert seq.gt_absolute() is None
    assert [p.name for p in seq.paths] == ["000009.png", "000010.png", "000011.png", "000100.png"]
    np.testing.assert_array_equal(seq.timestamps_us, [1574859771000000 + k * 250_000 for k in range(4)])
    for k, frame in enumerate(seq):
        assert frame.index == k and frame.gt_pose_rel is None
        assert frame.scan.timestamp_us == frame.timestamp_us == seq.timestamps_us[k]
        np.testing.assert_array_equal(frame.scan.power, sweep_image(frames[k]).T / np.float32(255))
    assert "radiate" in repr(seq) and "no ground truth" in repr(seq)
    assert read_sequence(tmp_path, format="radiate").paths == seq.paths


def test_time_file_may_list_more_frames_than_there_are_sweeps(tmp_path):
    write_radiate(tmp_path, frames=(2, 3), times=TIMES[1:3],
                  lines=[f"Frame: {k:06d} Time: {t}" for k, t in zip((1, 2, 3, 4), TIMES)])
    seq = read_sequence(tmp_path)
    np.testing.assert_array_equal(seq.timestamps_us, TIMES_US[1:3])
    # the period is measured over the whole file
    assert seq[0].scan.timestamps_us[1] - seq[0].scan.timestamps_us[0] == round(np.median(np.diff(TIMES_US[:4])) / A)


def test_sequence_errors(tmp_path):
    write_radiate(tmp_path / "a", frames=(1, 2, 3), times=TIMES[:3],
                  lines=[f"Frame: {k:06d} Time: {t}" for k, t in zip((1, 2), TIMES)])
    with pytest.raises(SequenceError, match=r"Navtech_Polar\.txt: no line for 000003\.png"):
        read_sequence(tmp_path / "a")

    write_radiate(tmp_path / "b")
    (tmp_path / "b" / "Navtech_Polar.txt").unlink()
    with pytest.raises(SequenceError, match=r"Navtech_Polar\.txt: no such file"):
        read_sequence(tmp_path / "b")

    write_radiate(tmp_path / "c")
    assert cv2.imwrite(str(tmp_path / "c" / "Navtech_Polar" / "first.png"), sweep_image())
    with pytest.raises(SequenceError, match=r"frame numbers .*first\.png"):
        read_sequence(tmp_path / "c")

    (tmp_path / "d" / "Navtech_Polar").mkdir(parents=True)
    with pytest.raises(SequenceError, match="holds no radar PNGs"):
        read_sequence(tmp_path / "d")
    with pytest.raises(SequenceError, match=r"Navtech_Polar/\*\.png \(RADIATE\)"):  # among the layouts looked for
        read_sequence(tmp_path / "b" / "Navtech_Polar")


def test_a_bad_sweep_in_a_sequence_fails_when_read(tmp_path):
    write_radiate(tmp_path, images=[sweep_image()] * 4 + [sweep_image().T.copy()])
    seq = read_sequence(tmp_path)  # lazily decoded: opening does not read the PNGs
    assert seq[3].scan.num_azimuths == A
    with pytest.raises(ScanFormatError, match="transpose"):
        seq[4]


# ---------------------------------------------------------------- the real sweeps


@pytest.fixture(scope="module")
def radiate_dir(real_data_dir):
    path = real_data_dir / "radiate-fog_6_0"
    if not (path / "Navtech_Polar").is_dir():
        pytest.skip(f"no RADIATE sweeps at {path}")
    return path


@pytest.mark.real
def test_real_radiate_sweeps_load(radiate_dir):
    files = sorted((radiate_dir / "Navtech_Polar").glob("*.png"))
    assert len(files) == 18
    starts = []
    for f in files:
        scan = load_scan(f)  # format detected from the folder name
        assert scan.power.shape == (400, 576) and scan.power.dtype == np.float32
        assert 0.0 <= scan.power.min() and scan.power.max() <= 1.0 and scan.power.max() > 0.1
        assert np.all(np.diff(scan.timestamps_us) > 0)
        assert 0.2e6 < scan.timestamps_us[-1] - scan.timestamps_us[0] < 0.3e6  # one 4 Hz turn
        assert scan.max_range_m == pytest.approx(100.0, abs=0.01)
        starts.append(scan.timestamp_us)
    gaps_s = np.diff(starts) / 1e6
    assert np.all(gaps_s > 0)
    assert 3.5 < 1.0 / np.median(gaps_s) < 4.5  # ≈ 4 Hz
    assert starts[0] == 1574859771744660  # "Frame: 000001 Time: 1574859771.744660272"


@pytest.mark.real
def test_real_radiate_sequence(radiate_dir):
    seq = read_sequence(radiate_dir)
    assert seq.format == "radiate" and len(seq) == 18 and seq.gt_relative is None
    assert [p.name for p in seq.paths] == [f"{k:06d}.png" for k in range(1, 19)]
    assert np.all(np.diff(seq.timestamps_us) > 0)
    assert seq[17].scan.timestamp_us == seq.timestamps_us[17]


@pytest.mark.real
def test_real_radiate_runs_through_a_shipped_cartesian_model(radiate_dir):
    """A Cartesian model trained on Oxford geometry (400 × 3768 bins of 4.32 cm) takes RADIATE's
    400 × 576 bins of 17.4 cm: no ModelMismatchError, finite poses (accuracy is not asserted:
    the shipped models are simulator-trained and being retrained)."""
    import radar_odom
    from radar_odom import RadarOdometer

    if "cart-0.4" not in radar_odom.pretrained_names():
        pytest.skip("no shipped cart-0.4 model in this checkout")
    odo = RadarOdometer(radar_odom.pretrained("cart-0.4"), threads=1)
    assert odo.info.sweep_geometry["num_bins"] != 576  # trained on another geometry
    seq = read_sequence(radiate_dir)
    ests = [odo.step(seq[k].scan) for k in range(4)]
    assert ests[0] is None
    for est in ests[1:]:
        assert np.all(np.isfinite(est.pose)) and np.all(np.isfinite(est.covariance))
        assert est.pose.shape == (3,) and est.covariance.shape == (3, 3)
    assert len(odo.trajectory) == 4 and np.all(np.isfinite(odo.trajectory.poses))


@pytest.mark.real
def test_real_radiate_azimuth_zero_points_forward(radiate_dir):
    """The reader's convention on real data: consecutive sweeps, as Cartesian images, match best
    when the world moves backwards along -x (the car drives forward at ≈ 10 m/s, README: 9–13),
    and not sideways; with azimuth 0 pointing elsewhere the motion would show along another axis.
    The sweep-fixed pattern (range rings, azimuth gain, the car itself) is removed first: it
    would otherwise make zero shift the best match."""
    from radar_odom import polar_to_cartesian
    from radar_odom.scan import RadarScan

    res, w = 0.25, 512
    imgs = []
    for frame in read_sequence(radiate_dir):
        s = frame.scan
        p = np.clip(s.power - np.median(s.power, axis=0, keepdims=True), 0, None)  # range profile out
        flat = RadarScan.from_arrays(s.timestamps_us, s.azimuths_rad, p / max(float(p.max()), 1e-6),
                                     range_resolution_m=s.range_resolution_m)
        imgs.append(polar_to_cartesian(flat, res, w, near_range_m=4.0).astype(np.float64))
    fixed = np.mean(imgs, axis=0)
    r = np.hypot(*(np.mgrid[:w, :w] - (w - 1) / 2))
    disc = r < w / 2 - 40  # no wrap-around of the circular correlation
    shifts = []
    for a, b in zip(imgs[:-1], imgs[1:]):
        fa, fb = np.fft.fft2((a - fixed) * disc), np.fft.fft2((b - fixed) * disc)
        cross = fa * np.conj(fb)
        corr = np.fft.fftshift(np.real(np.fft.ifft2(cross / (np.abs(cross) + 1e-12))))
        c = w // 2
        corr[c - 2 : c + 3, c - 2 : c + 3] = -np.inf  # not the sweep-fixed remainder
        i, j = np.unravel_index(np.argmax(corr), corr.shape)
        # the peak sits at minus the content's shift (rows down = towards -x, columns = +y):
        # (metres the world moved towards -x, metres it moved along -y)
        shifts.append((-(i - c) * res, (j - c) * res))
    shifts = np.array(shifts)
    moved_back = shifts[:, 0]
    assert np.all(moved_back > 1.5) and np.all(moved_back < 4.0), shifts  # forward at 6–16 m/s
    assert np.all(np.abs(shifts[:, 1]) <= 2 * res), shifts  # not sideways



# ---------------------------------------------------------------- unpadded nanoseconds
# Some RADIATE time files print the nanoseconds without zero padding: ".4512151" is 4 512 151 ns.


def _time_lines(times, first_frame=1) -> str:
    return "\n".join(f"Frame: {first_frame + k:06d} Time: {t}" for k, t in enumerate(times)) + "\n"


def test_unpadded_nanoseconds_are_read_as_nanoseconds():
    # 4 Hz across a second boundary; read as decimals line 2 (.4512151) would jump back on line 3
    text = _time_lines(["1549986597.751825190", "1549986598.4512151", "1549986598.253629300",
                        "1549986598.503659888", "1549986598.750000499", "1549986599.500"])
    parsed = parse_frame_times(text, "t.txt")
    assert parsed.reading == NANOSECONDS and parsed.frames == (1, 2, 3, 4, 5, 6)
    # ns rounded half up to µs, exactly: 190 → 0, 888 → 1, 499 → 0, 500 → 1
    assert parse_radiate_times(text, "t.txt") == {
        1: 1549986597751825, 2: 1549986598004512, 3: 1549986598253629,
        4: 1549986598503660, 5: 1549986598750000, 6: 1549986599000001}


def test_short_decimal_fractions_stay_decimals():
    # read as nanoseconds, .25 / .5 / .75 would be 25, 5, 75 ns: not increasing
    text = _time_lines(["1574859771.0", "1574859771.25", "1574859771.5", "1574859771.75"])
    parsed = parse_frame_times(text, "t.txt")
    assert parsed.reading == DECIMAL
    assert parsed.times_us == (1574859771000000, 1574859771250000, 1574859771500000, 1574859771750000)


def test_nine_digit_fractions_mean_the_same_either_way():
    parsed = parse_frame_times(_time_lines(TIMES), "t.txt")
    assert parsed.reading == AGREE and parsed.times_us == tuple(TIMES_US)
    # no fraction, or a fraction too long to count nanoseconds: decimals only
    assert parse_frame_times(_time_lines(["1574859771", "1574859772"]), "t").reading == AGREE
    assert parse_frame_times(_time_lines(["1574859771.1", "1574859772.0000000001"]), "t").reading == DECIMAL


def test_when_both_readings_increase_the_more_regular_one_wins():
    # 4 Hz; the last line read as decimals (.5) increases too, but 0.75 s after the one before
    text = _time_lines(["1574859771.000000000", "1574859771.250000000", "1574859771.500000000",
                        "1574859771.750000000", "1574859772.5000000"])
    parsed = parse_frame_times(text, "t.txt")
    assert parsed.reading == NANOSECONDS and parsed.times_us[-1] == 1574859772005000  # 5 000 000 ns
    text = _time_lines(["1574859771.000000000", "1574859771.25", "1574859771.500000000",
                        "1574859771.750000000", "1574859772.000000000"])
    assert parse_frame_times(text, "t.txt").reading == DECIMAL  # .25 s fits the 4 Hz spacing
    # equally regular (a single odd first spacing either way): the decimal reading, RADIATE's documented one
    text = _time_lines(["1574859771.5", "1574859771.977525228", "1574859772.213924306"])
    assert parse_frame_times(text, "t.txt").reading == DECIMAL


def test_times_that_fail_both_readings_name_the_line_and_both_readings():
    text = _time_lines(["1574859771.900000000", "1574859771.95", "1574859771.5"])
    with pytest.raises(SequenceError) as err:
        parse_radiate_times(text, "t.txt")
    msg = str(err.value)
    assert msg.startswith("t.txt, line 3: frame 3 at 1574859771.500000 s is not after frame 2")
    assert "decimals" in msg and "unpadded nanoseconds" in msg and "line 2: frame 2" in msg


def test_a_sample_listed_twice_at_one_time_is_allowed_only_where_asked():
    # the GNSS/INS file's form: consecutive frames, identical times, unpadded nanoseconds
    text = _time_lines(["1549986597.950734000", "1549986597.950734000", "1549986598.734000",
                        "1549986598.734000", "1549986598.50734000", "1549986598.50734000"], first_frame=2009)
    parsed = parse_frame_times(text, "g.txt", strictly_increasing=False)
    assert parsed.reading == NANOSECONDS and parsed.frames[0] == 2009 and parsed.lines == (1, 2, 3, 4, 5, 6)
    assert parsed.times_us == (1549986597950734, 1549986597950734, 1549986598000734, 1549986598000734,
                               1549986598050734, 1549986598050734)
    with pytest.raises(SequenceError, match=r"g\.txt, line 2: frame 2010 .* is not after frame 2009"):
        parse_frame_times(text, "g.txt")
    with pytest.raises(SequenceError, match=r"line 5: frame 2013 at .* is before frame 2012"):
        parse_frame_times(_time_lines(["1.100000000", "1.100000000", "1.200000000", "1.200000000", "1.150000000"],
                                      first_frame=2009), "g.txt",
                          strictly_increasing=False)


@pytest.mark.parametrize("line,match", [
    ("Frame: 000002 Time: 1574859771744660272", r"line 2: time 1574859771744660272 is not UNIX seconds"),
    ("Frame: 000002 Time: 1574859771.7446x", r"line 2: cannot read"),
    ("Frame: 000002 Time: \u0661\u0662.5", r"line 2: cannot read"),  # non-ASCII digits
])
def test_garbled_times(line, match):
    with pytest.raises(SequenceError, match=match):
        parse_radiate_times(f"Frame: 000001 Time: 1574859771.5\n{line}\n", "t.txt")


@pytest.fixture(scope="module")
def edinburgh_dir(real_data_dir):
    path = real_data_dir / "radiate-2019-02-12-edinburgh"
    if not (path / "Navtech_Polar.txt").is_file():
        pytest.skip(f"no RADIATE city drive at {path}")
    return path


@pytest.mark.real
def test_real_time_file_with_unpadded_nanoseconds(edinburgh_dir):
    path = edinburgh_dir / "Navtech_Polar.txt"
    assert "Frame: 000203 Time: 1549986598.4512151" in path.read_text().splitlines()
    parsed = parse_frame_times(path.read_text(), str(path))
    assert parsed.reading == NANOSECONDS
    times = read_radiate_times(path)
    assert len(times) == 280 and sorted(times) == list(range(201, 481))
    stamps = np.array([times[f] for f in sorted(times)])
    assert np.all(np.diff(stamps) > 0)
    assert np.median(np.diff(stamps)) / 1e6 == pytest.approx(0.25, abs=0.005)
    assert times[203] == 1549986598004512  # 1549986598 s + 4 512 151 ns
    raw = read_sequence(edinburgh_dir, repair_stamps=False)
    assert len(raw) == 280 and raw.timestamps_us[2] == 1549986598004512
    # by default the times are the fitted time base's (`io.timebase`): that stamp is on time, within the host's jitter
    from radar_odom.errors import StampWarning

    with pytest.warns(StampWarning):
        seq = read_sequence(edinburgh_dir)
    assert abs(int(seq.timestamps_us[2]) - 1549986598004512) < seq.time_base.tolerance_us


def test_late_stamps_are_put_back_on_the_sensor_period_with_a_warning(tmp_path):
    """RADIATE stamps sweeps on the recording host: a run of late stamps (one ≈ 0.5 s interval, then
    short ones until back on the 0.25 s rhythm; the shared city drive has three) is put back, and the
    sweeps' azimuth times with it; ``repair_stamps=False`` keeps them as recorded."""
    from radar_odom.errors import StampWarning

    n, period = 40, 250_000
    true = 1574859771_000_000 + np.arange(n) * period
    late = true + np.array([max(0, 240_000 - 20_000 * (k - 10)) if k >= 10 else 0 for k in range(n)])
    frames = tuple(range(1, n + 1))
    times = [f"{t // 1_000_000}.{t % 1_000_000:06d}" for t in late]
    write_radiate(tmp_path, frames=frames, times=times, images=[sweep_image(0)] * n)
    with pytest.warns(StampWarning, match=r"12 sweep stamps were late \(up to 240 ms, in 1 run.*repair_stamps=False"):
        seq = read_sequence(tmp_path)
    np.testing.assert_array_equal(seq.timestamps_us, true)
    np.testing.assert_array_equal(seq.stamp_corrections_us, late - true)
    scan = seq[10].scan  # the first late sweep: every azimuth time moved with its stamp
    assert scan.timestamp_us == true[10]
    np.testing.assert_array_equal(scan.timestamps_us, load_radiate(seq.paths[10]).timestamps_us - 240_000)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        raw = read_sequence(tmp_path, repair_stamps=False)
    np.testing.assert_array_equal(raw.timestamps_us, late)
    assert raw[10].scan.timestamp_us == late[10] and not raw.stamp_corrections_us.any()

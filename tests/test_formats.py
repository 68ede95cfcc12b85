"""Sweep files: the Oxford layout byte for byte, Boreas and MulRan specifics, and bad input."""
import math
from datetime import datetime, timezone

import cv2
import numpy as np
import pytest

from radar_odom import RadarScan, ScanFormatError, load_scan, write_scan
from radar_odom.io import detect_format

T0_US = 1547131046353776  # an Oxford sweep name
TWO_PI = 2 * math.pi


def oxford_image(timestamps, counts, valid_byte, power_u8) -> np.ndarray:
    """Rows built byte by byte from the documented layout (independent of the SDK's writer)."""
    rows = []
    for t, c, v, p in zip(timestamps, counts, valid_byte, power_u8):
        head = int(t).to_bytes(8, "little", signed=True) + int(c).to_bytes(2, "little") + bytes([int(v)])
        rows.append(np.frombuffer(head + bytes(np.asarray(p, dtype=np.uint8)), dtype=np.uint8))
    return np.stack(rows)


def save_png(path, img) -> str:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), img)
    return path


def small_sweep(a=8, b=64, t0=T0_US, seed=0, step_us=625):
    rng = np.random.default_rng(seed)
    ts = t0 + np.arange(a) * step_us
    counts = np.arange(a) * 14
    return ts, counts, rng.integers(0, 256, (a, b), dtype=np.uint8)


# ---------------------------------------------------------------- Oxford, the real layout


def test_real_oxford_layout_reads_exactly_and_writes_back_the_same_pixels(tmp_path):
    a, b = 400, 3768
    rng = np.random.default_rng(1)
    ts = T0_US + np.arange(a, dtype=np.int64) * 625  # 250 ms sweep
    counts = np.arange(a) * 14  # 0 .. 5586: the last row sits just below 2π (the seam)
    valid = np.full(a, 255)
    power = rng.integers(0, 256, (a, b), dtype=np.uint8)
    invalid = [5, 6, 399]  # garbage headers, as the sensor leaves them
    for r in invalid:
        valid[r], counts[r], ts[r] = 0, 65535, 0
        power[r] = 0
    img = oxford_image(ts, counts, valid, power)
    assert img.shape == (400, 3779) and img.dtype == np.uint8
    path = save_png(tmp_path / "radar" / f"{T0_US}.png", img)

    scan = load_scan(path)
    assert scan.power.shape == (400, 3768) and scan.power.dtype == np.float32
    good = np.setdiff1d(np.arange(a), invalid)
    np.testing.assert_array_equal(scan.timestamps_us[good], ts[good])
    assert scan.timestamp_us == T0_US
    np.testing.assert_array_equal(scan.valid, valid == 255)
    assert scan.invalid_rows == (5, 6, 399)
    np.testing.assert_array_equal(scan.power, power.astype(np.float32) / np.float32(255))
    # every azimuth, invalid ones interpolated/extrapolated on the 14-count step
    np.testing.assert_allclose(scan.azimuths_rad, np.arange(a) * 14 * TWO_PI / 5600, rtol=0, atol=1e-6)
    assert scan.azimuths_rad[0] == 0.0 and scan.azimuths_rad[-1] < TWO_PI
    assert np.all(np.diff(scan.azimuths_rad) > 0)
    assert scan.range_resolution_m == 0.0432 and scan.range_offset_m == 0.0

    out = write_scan(tmp_path / "copy.png", scan)
    np.testing.assert_array_equal(cv2.imread(str(out), cv2.IMREAD_UNCHANGED), img)


def test_invalid_rows_are_zeroed_and_reported_when_read(tmp_path):
    ts, counts, power = small_sweep()
    valid = np.full(8, 255)
    valid[2] = 7  # "anything else = invalid"
    path = save_png(tmp_path / "s.png", oxford_image(ts, counts, valid, power))
    scan = load_scan(path, "oxford")
    assert scan.invalid_rows == (2,)
    assert not scan.valid[2] and np.all(scan.power[2] == 0) and np.any(power[2] > 0)
    np.testing.assert_array_equal(scan.power[3], power[3] / np.float32(255))
    # written back: flag 0, no power; every other byte unchanged
    back = cv2.imread(str(write_scan(tmp_path / "w.png", scan)), cv2.IMREAD_UNCHANGED)
    expect = oxford_image(ts, counts, np.where(valid == 255, 255, 0), np.where(valid[:, None] == 255, power, 0))
    np.testing.assert_array_equal(back, expect)


def test_write_then_load_is_identity_with_derived_encoder_counts(tmp_path):
    a = 256
    power = (np.arange(a * 2) % 256).astype(np.uint8).reshape(a, 2)  # every byte value
    az = np.arange(a) * 21 * TWO_PI / 5600
    ts = T0_US + np.arange(a) * 977
    valid = np.ones(a, dtype=bool)
    valid[[0, 100]] = False
    scan = RadarScan.from_arrays(ts, az, power, valid=valid)
    assert scan.encoder_counts is None
    path = write_scan(tmp_path, scan)  # a folder: the Oxford name is used
    assert path.name == f"{T0_US}.png"
    back = load_scan(path)
    np.testing.assert_array_equal(back.timestamps_us, scan.timestamps_us)
    np.testing.assert_array_equal(back.power, scan.power)
    np.testing.assert_array_equal(back.valid, scan.valid)
    np.testing.assert_allclose(back.azimuths_rad, scan.azimuths_rad, atol=1e-6)
    np.testing.assert_array_equal(back.encoder_counts, np.arange(a) * 21)
    assert back.invalid_rows == (0, 100)
    assert back.geometry == scan.geometry


def test_oxford_resolution_is_a_parameter(tmp_path):
    path = save_png(tmp_path / "s.png", oxford_image(*small_sweep()[:2], [255] * 8, small_sweep()[2]))
    assert load_scan(path, range_resolution_m=0.0438).range_resolution_m == 0.0438


# ---------------------------------------------------------------- Boreas


def boreas_sweep(tmp_path, name_us, counts=None):
    ts, c, power = small_sweep(t0=name_us - 4 * 625)
    counts = c if counts is None else counts
    seq = tmp_path / f"boreas-{name_us}"
    (seq / "applanix").mkdir(parents=True)
    # column 10 is unused by Boreas: zeros must not invalidate rows
    return save_png(seq / "radar" / f"{name_us}.png", oxford_image(ts, counts, [0] * 8, power)), power


def test_boreas_resolution_by_date_and_range_offset(tmp_path):
    change = int(datetime(2021, 9, 21, tzinfo=timezone.utc).timestamp()) * 1_000_000
    before, _ = boreas_sweep(tmp_path, change - 1_000_000)
    after, power = boreas_sweep(tmp_path, change + 1_000_000)
    assert detect_format(before) == "boreas"
    s_before, s_after = load_scan(before), load_scan(after)
    assert s_before.range_resolution_m == 0.0596
    assert s_after.range_resolution_m == 0.04381
    assert s_after.range_offset_m == -0.31
    assert s_after.max_range_m == pytest.approx(-0.31 + 64 * 0.04381)
    assert s_after.valid.all() and s_after.invalid_rows == ()
    np.testing.assert_array_equal(s_after.power, power / np.float32(255))
    assert load_scan(after, range_resolution_m=0.05).range_resolution_m == 0.05


def test_boreas_keeps_non_uniform_azimuths(tmp_path):
    counts = np.array([3, 10, 24, 31, 45, 52, 66, 73])  # alternating 7/14 steps
    path, _ = boreas_sweep(tmp_path, 1606417230036848, counts=counts)
    scan = load_scan(path, "boreas")
    np.testing.assert_allclose(scan.azimuths_rad, counts * math.pi / 2800, atol=1e-7)


# ---------------------------------------------------------------- MulRan


def test_mulran_raw_transposed_png_with_ns_name(tmp_path):
    a, b = 16, 64
    power = np.random.default_rng(2).integers(0, 256, (a, b), dtype=np.uint8)
    end_ns = 1566535954883011000
    path = save_png(tmp_path / "KAIST01" / "polar" / f"{end_ns}.png", power.T.copy())  # rows = bins
    assert detect_format(path) == "mulran"
    scan = load_scan(path)
    assert scan.power.shape == (a, b)
    np.testing.assert_array_equal(scan.power, power / np.float32(255))
    assert scan.range_resolution_m == 0.05952
    np.testing.assert_allclose(scan.azimuths_rad, np.arange(a) * TWO_PI / a, atol=1e-7)
    end_us = end_ns // 1000
    assert scan.timestamps_us[-1] == end_us  # the name is the END of the sweep
    assert scan.timestamps_us[0] == end_us - 15 * 250_000 // 16
    assert np.all(np.diff(scan.timestamps_us) == 15625)


def test_mulran_raw_needs_a_timestamp_name(tmp_path):
    path = save_png(tmp_path / "polar" / "sweep.png", np.zeros((64, 16), np.uint8))
    with pytest.raises(ScanFormatError, match="end-of-sweep time in ns") as e:
        load_scan(path)
    assert str(path) in str(e.value)


@pytest.mark.parametrize("folder", ["polar_oxford_form", "elsewhere"])
def test_mulran_oxford_form_has_ns_header_converted_to_us(tmp_path, folder):
    ts_us, counts, power = small_sweep()
    ts_ns = ts_us * 1000 + 123  # sub-µs digits are floored away
    path = save_png(tmp_path / folder / f"{ts_ns[-1]}.png", oxford_image(ts_ns, counts, [255] * 8, power))
    scan = load_scan(path, "mulran")  # "elsewhere": the header is recognised by its content
    np.testing.assert_array_equal(scan.timestamps_us, ts_us)
    assert scan.range_resolution_m == 0.05952
    np.testing.assert_array_equal(scan.power, power / np.float32(255))


# ---------------------------------------------------------------- bad input


def raises(path, match, **kw):
    with pytest.raises(ScanFormatError, match=match) as e:
        load_scan(path, **kw)
    assert str(path) in str(e.value)  # the message names the file


def test_not_a_png_empty_missing(tmp_path):
    (tmp_path / "a.png").write_text("hello radar")
    raises(tmp_path / "a.png", "not a PNG")
    (tmp_path / "b.png").write_bytes(b"")
    raises(tmp_path / "b.png", "empty")
    raises(tmp_path / "missing.png", "no such file")


def test_truncated_png(tmp_path):
    full = save_png(tmp_path / "full.png", oxford_image(*small_sweep(b=2000)[:2], [255] * 8, small_sweep(b=2000)[2]))
    data = full.read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    raises(tmp_path / "cut.png", "truncated")


def test_wrong_bit_depth_and_channels(tmp_path):
    raises(save_png(tmp_path / "d16.png", np.zeros((8, 75), np.uint16)), "8-bit.*16-bit")
    raises(save_png(tmp_path / "rgb.png", np.zeros((8, 75, 3), np.uint8)), "3 channels")


def test_wrong_width_and_height(tmp_path):
    ts, counts, power = small_sweep()
    path = save_png(tmp_path / "s.png", oxford_image(ts, counts, [255] * 8, power))
    raises(path, r"width must be 11 \+ bins = 3779 for 3768 bins, got 75", num_bins=3768)
    raises(path, "height must equal the azimuth count: expected 400, got 8", num_azimuths=400)
    raises(save_png(tmp_path / "narrow.png", np.zeros((8, 12), np.uint8)), "width must be 11 header bytes")
    raises(save_png(tmp_path / "one.png", oxford_image(ts[:1], counts[:1], [255], power[:1])), "height")


def test_non_increasing_encoder_counts(tmp_path):
    ts, counts, power = small_sweep()
    counts[5] = counts[4]
    path = save_png(tmp_path / "s.png", oxford_image(ts, counts, [255] * 8, power))
    raises(path, "encoder counts must increase.*row 5")
    counts[5] = 6000  # beyond one turn
    counts[6:] = [6014, 6028]
    raises(save_png(tmp_path / "t.png", oxford_image(ts, counts, [255] * 8, power)), "not below 5600")


def test_every_row_invalid(tmp_path):
    ts, counts, power = small_sweep()
    raises(
        save_png(tmp_path / "s.png", oxford_image(ts, counts, [0] * 8, power)), "every azimuth row is marked invalid"
    )


def test_bad_arrays_from_a_driver():
    ts, counts, power = small_sweep()
    az = counts * TWO_PI / 5600
    bad = power.astype(np.float32) / 255
    bad[3, 3] = np.nan
    with pytest.raises(ScanFormatError, match="NaN"):
        RadarScan.from_arrays(ts, az, bad, source="driver")
    with pytest.raises(ScanFormatError, match=r"driver: timestamps_us has shape \(7,\) but power has 8"):
        RadarScan.from_arrays(ts[:7], az, power, source="driver")
    with pytest.raises(ScanFormatError, match="every azimuth row"):
        RadarScan.from_arrays(ts, az, power, valid=np.zeros(8, bool))


def test_unknown_format(tmp_path):
    with pytest.raises(ValueError, match="unknown radar format 'kitti'"):
        load_scan(tmp_path / "x.png", "kitti")


def test_an_explicit_format_that_the_folder_contradicts_warns(tmp_path):
    """`load_scan(oxford_png, format="mulran")` read the sweep with MulRan's range resolution,
    silently: now a warning names both layouts (the sweep is still read as asked)."""
    import warnings

    from radar_odom.errors import FormatWarning
    from radar_odom.sim.writer import write_drive

    seq = write_drive(tmp_path / "seq", seed=2, frames=1, progress=False)
    png = next((seq / "radar").glob("*.png"))
    with pytest.warns(FormatWarning) as record:  # the header and the folder both contradict it: two warnings
        scan = load_scan(png, format="mulran")
    said = [str(w.message) for w in record]
    assert any("read as 'mulran' as asked, but its header holds µs timestamps" in m for m in said), said
    assert any("its folder is laid out as 'oxford'" in m for m in said), said
    assert scan.range_resolution_m == pytest.approx(0.05952)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_scan(png, format="oxford")
        load_scan(png, format="mulran", range_resolution_m=0.0432)  # told the resolution: nothing to warn of
    # a folder that names its dataset for certain
    applanix = seq / "applanix"
    applanix.mkdir()
    with pytest.warns(FormatWarning, match=r"read as 'oxford' as asked, but its folder is laid out as 'boreas'"):
        load_scan(png, format="oxford")


def test_boreas_asked_of_an_oxford_sweep_warns_by_folder_and_by_content(tmp_path):
    """`read_sequence(oxford, format="boreas")` / `load_scan(oxford_png, format="boreas")` read 0.0596 m
    bins instead of 0.0432 (steps 33 % long), silently, because a radar/ folder without applanix/ was taken
    for a bare one. radar.timestamps beside radar/, a name that is the first azimuth's time and 3768 bins all
    say Oxford; a Boreas sweep (named by its middle) read as Oxford in a bare folder says Boreas."""
    import shutil
    import warnings

    from radar_odom import read_sequence
    from radar_odom.errors import FormatWarning
    from radar_odom.sim.writer import write_drive

    seq = write_drive(tmp_path / "seq", seed=2, frames=2, progress=False)
    png = sorted((seq / "radar").glob("*.png"))[0]
    with pytest.warns(FormatWarning, match=r"sweeps read as 'boreas' as asked, but its folder is laid out as "
                                           r"'oxford' \(radar\.timestamps lies beside radar/"):
        load_scan(png, format="boreas")
    with pytest.warns(FormatWarning, match=r"read as 'boreas' as asked, but its folder is laid out as 'oxford'"):
        read_sequence(seq, format="boreas")  # said at open, before any sweep is decoded
    bare = tmp_path / "bare" / "radar"
    bare.mkdir(parents=True)
    shutil.copy(png, bare / png.name)
    with pytest.warns(FormatWarning) as rec:
        load_scan(bare / png.name, format="boreas")
    text = str(rec[0].message)
    assert "file name is its first azimuth's time, as Oxford names sweeps" in text and "3768 range bins" in text
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_scan(bare / png.name, format="oxford")
        load_scan(bare / png.name)  # detected: nothing was asked, nothing contradicted
    # a Boreas sweep (named by its middle) read as Oxford in a bare folder
    boreas_png, _ = boreas_sweep(tmp_path / "b", 1606417230036848)
    shutil.rmtree(boreas_png.parent.parent / "applanix")
    ts, counts, power = small_sweep(t0=1606417230036848 - 4 * 625)
    save_png(boreas_png, oxford_image(ts, counts, [255] * 8, power))  # valid rows, as Oxford reads them
    with pytest.warns(FormatWarning, match=r"read as 'oxford' as asked, but its file name is its middle azimuth's"):
        load_scan(boreas_png, format="oxford")


@pytest.mark.parametrize("bad", [None, 3, 1.5])
def test_a_sweep_path_that_is_not_a_path_says_so(bad, tmp_path):
    """`load_scan(None)` raised pathlib's TypeError from deep inside; bytes paths were refused."""
    with pytest.raises(TypeError, match=rf"a sweep path must be a file path \(str, bytes or os.PathLike\), got "
                                        rf"{type(bad).__name__}"):
        load_scan(bad)
    path = save_png(tmp_path / "radar" / f"{T0_US}.png", oxford_image(*small_sweep()[:2], [255] * 8, small_sweep()[2]))
    assert load_scan(bytes(path)).timestamp_us == T0_US


@pytest.mark.parametrize("fill, what", [
    (0, r"400 of 400 valid rows hold azimuth times at or before 1970 \(the lowest: 0 µs\)"),
    (-1, r"400 of 400 valid rows hold azimuth times at or before 1970 \(the lowest: -1 µs\)"),
    (T0_US, r"all 400 valid rows hold the same azimuth time"),
])
def test_impossible_header_timestamps_are_refused(tmp_path, fill, what):
    """Header times of all zeros or all 0xFF bytes (−1) were read as a sweep at 0 or −1 µs without a word,
    although the file name carries the sweep's time. They are a corrupt header: ScanFormatError (a run skips
    the sweep as unreadable, as it skips one whose header breaks the time order)."""
    a, b = 400, 16
    _, counts, power = small_sweep(a=a, b=b)
    counts = np.arange(a) * 14
    img = oxford_image([fill] * a, counts, [255] * a, power[:1].repeat(a, 0))
    path = save_png(tmp_path / "radar" / f"{T0_US}.png", img)
    with pytest.raises(ScanFormatError, match=rf"{T0_US}\.png: {what}.*\(its file name says {T0_US}\); the header's "
                                              r"timestamps are corrupt"):
        load_scan(path)

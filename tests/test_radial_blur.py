"""The radial-only feature blur (`GridProfile.feature_radial_blur_px`, `model.radial_blur_images`):
a point spreads along the direction from the sensor and not across it, whatever varies with the
azimuth only is kept, a ring's radial profile is the 1D Gaussian blur of it, the field off is the
previous model, and the blur exports to ONNX without constant tables."""
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import test_model as model_tests  # noqa: E402  (its tiny grid)

from radar_odom.profiles import OPTIONAL_FIELDS, GridProfile, get_profile  # noqa: E402
from radar_odom_export import model as model_module  # noqa: E402
from radar_odom_export.model import MaskedCorrelator, lowpass_images, radial_blur_images  # noqa: E402

pytestmark = pytest.mark.torch

W = 101  # odd: the centre (50, 50) is a pixel
C = (W - 1) / 2


def _grid(w=W):
    idx = torch.arange(w, dtype=torch.float64) - (w - 1) / 2
    return idx[:, None].expand(w, w), idx[None, :].expand(w, w)


def _point_moments(offset, sigma):
    """(mass, mean along u, variance along u, variance across u) of a point at ``offset`` (rows, cols)
    from the centre after the radial blur; u = the unit radial direction of the point."""
    r, q = int(C + offset[0]), int(C + offset[1])
    x = torch.zeros(1, W, W, dtype=torch.float64)
    x[0, r, q] = 1.0
    y = radial_blur_images(x, sigma)[0]
    rows, cols = _grid()
    dr, dq = rows - (r - C), cols - (q - C)
    u = torch.tensor(offset, dtype=torch.float64)
    u = u / u.norm()
    along, across = dr * u[0] + dq * u[1], -dr * u[1] + dq * u[0]
    mass = float(y.sum())
    mean = float((y * along).sum()) / mass
    return mass, mean, float((y * (along - mean) ** 2).sum()) / mass, float((y * across**2).sum()) / mass


@pytest.mark.parametrize("offset", [(0, 30), (21, 21), (-12, 27)])
@pytest.mark.parametrize("sigma", [1.0, 1.5])
def test_a_point_spreads_along_the_radial_direction_only(offset, sigma):
    mass, _, var_along, var_across = _point_moments(offset, sigma)
    assert mass == pytest.approx(1.0, rel=1e-5)  # away from the border and the centre
    assert var_along == pytest.approx(sigma**2, rel=0.25)
    limit = 0.01 if offset[0] == 0 else 0.1  # axis-aligned: the row carries it; a diagonal: a little more
    assert abs(var_across) < limit * sigma**2
    # an isotropic blur of the same sigma spreads across as much as along: the test can tell them apart
    x = torch.zeros(1, W, W, dtype=torch.float64)
    x[0, int(C + offset[0]), int(C + offset[1])] = 1.0
    iso = lowpass_images(x, sigma)[0]
    rows, cols = _grid()
    u = torch.tensor(offset, dtype=torch.float64) / math.hypot(*offset)
    across = -(rows - offset[0]) * u[1] + (cols - offset[1]) * u[0]
    assert float((iso * across**2).sum()) > 0.5 * sigma**2


def test_zero_sigma_is_the_images_themselves():
    x = torch.rand(2, 32, 32, generator=torch.Generator().manual_seed(0))
    assert radial_blur_images(x, 0.0) is x


def test_content_that_varies_with_the_azimuth_only_is_kept():
    """Spokes (a function of the azimuth alone) are constant along every ray: the radial blur keeps
    them where an isotropic blur of the same sigma smooths them away."""
    rows, cols = _grid()
    theta = torch.atan2(cols, rows)
    spokes = (1.0 + torch.cos(8 * theta))[None]
    radius = torch.sqrt(rows**2 + cols**2)
    annulus = (radius > 15) & (radius < 35)  # away from the centre and from the zero border
    for sigma in (1.0, 2.0):
        radial = radial_blur_images(spokes, sigma)[0]
        iso = lowpass_images(spokes, sigma)[0]
        radial_err = float((radial - spokes[0])[annulus].abs().max())
        iso_err = float((iso - spokes[0])[annulus].abs().max())
        assert radial_err < 0.05 * iso_err, (sigma, radial_err, iso_err)


def test_a_ring_is_blurred_along_the_radius_as_a_1d_gaussian():
    """A ring of radial profile exp(−(r − r0)²/2s²) blurred along the radius by σ is the 1D Gaussian
    blur of that profile (amplitude s/√(s² + σ²), width √(s² + σ²)), at every azimuth alike."""
    rows, cols = _grid()
    radius = torch.sqrt(rows**2 + cols**2)
    r0, s, sigma = 30.0, 1.5, 2.0
    ring = torch.exp(-((radius - r0) ** 2) / (2 * s**2))[None]
    out = radial_blur_images(ring, sigma)[0]
    width2 = s**2 + sigma**2
    expected = s / math.sqrt(width2) * torch.exp(-((radius - r0) ** 2) / (2 * width2))
    near = (radius - r0).abs() < 8
    assert float((out - expected)[near].abs().max()) < 0.03  # peak 0.6: within 5 %
    # the same at every azimuth: the ring's tangential profile at r0 is flat
    on_ring = (radius - r0).abs() < 0.5
    assert float(out[on_ring].max() - out[on_ring].min()) < 0.08 * float(out[on_ring].mean())


# ------------------------------------------------------------------ the profile field and the model
def tiny_profile(**kw):
    """test_model's tiny grid at W = 64 (room for a blur of 1–3 px inside the ±6 m window)."""
    return model_tests.tiny_profile(**{"width_px": 64, "max_translation_m": 6.0, **kw})


def test_the_field_is_optional_in_metadata_and_validated():
    assert OPTIONAL_FIELDS["feature_radial_blur_px"] == 0.0
    p = get_profile("cart-0.4")
    assert p.feature_radial_blur_px == 0.0
    text = p.to_metadata()["radar_odom.profile"]
    assert "feature_radial_blur_px" not in text  # the shipped files' digest is unchanged
    q = p.with_(feature_radial_blur_px=1.0)
    assert '"feature_radial_blur_px": 1.0' in q.to_metadata()["radar_odom.profile"]
    assert GridProfile.from_metadata(q.to_metadata()) == q
    assert GridProfile.from_metadata(p.to_metadata()) == p  # a file without the key reads 0
    with pytest.raises(ValueError, match="feature_radial_blur_px.*'cart-0.4'|'cart-0.4'.*feature_radial_blur_px"):
        p.with_(feature_radial_blur_px=-0.5)
    with pytest.raises(ValueError, match="feature_radial_blur_px"):
        p.with_(feature_radial_blur_px=p.translation_cells / 2 + 0.5)
    with pytest.raises(ValueError, match="feature_radial_blur_px"):
        p.with_(feature_radial_blur_px=float("nan"))
    p.with_(feature_radial_blur_px=p.translation_cells / 2)  # the bound itself is allowed


def _features(profile, sweep):
    torch.manual_seed(0)
    model = MaskedCorrelator(profile, masking="learned").eval()
    with torch.no_grad():
        return model.sweep_features(sweep)


def test_the_field_off_is_the_previous_model_and_on_blurs_first(monkeypatch):
    sweep = torch.rand(2, 64, 64, generator=torch.Generator().manual_seed(1))
    base = tiny_profile(feature_highpass_px=8.0)
    calls = []
    real = model_module.radial_blur_images

    def spy(images, sigma):
        calls.append(sigma)
        return real(images, sigma)

    monkeypatch.setattr(model_module, "radial_blur_images", spy)
    assert "feature_radial_blur_px" not in base.to_dict()  # as a file without the field reads
    before = _features(GridProfile.from_dict(base.to_dict()), sweep)
    off = _features(base.with_(feature_radial_blur_px=0.0), sweep)
    assert calls == [] and torch.equal(before, off)  # bit-identical, the blur never runs
    on = _features(base.with_(feature_radial_blur_px=1.0), sweep)
    assert calls == [1.0]
    assert float((on - off).abs().max()) > 1e-3
    # the radial blur runs before the high-pass: the same as blurring the unfiltered features by hand
    plain = _features(tiny_profile(), sweep)
    support = MaskedCorrelator(base).support
    blurred = radial_blur_images(plain * support, 1.0)
    by_hand = (blurred - lowpass_images(blurred * support, 8.0)) * support
    assert torch.allclose(on, by_hand, atol=1e-5)


def test_the_radial_blur_exports_to_onnx_without_tables(tmp_path):
    pytest.importorskip("onnxruntime")
    from radar_odom.onnx_model import OnnxModel
    from radar_odom_export.onnx_export import example_inputs, export_model

    w = 128  # wide enough that the a, b, c maps are over the exporter's constant-folding input limit
    profile = GridProfile("tiny-export", resolution_m=1.6, width_px=w, max_translation_m=4.8,
                          rotation_range_rad=0.1, rotation_step_rad=0.05, unet_base_channels=4, unet_depth=3,
                          feature_highpass_px=8.0)
    sizes = {}
    for sigma in (0.0, 1.0):
        torch.manual_seed(0)
        model = MaskedCorrelator(profile.with_(feature_radial_blur_px=sigma), masking="learned").eval()
        path = tmp_path / f"r{sigma}.onnx"
        report = export_model(model, path, verify=True)  # torch vs onnxruntime on fresh inputs
        assert report.max_pose_diff < 1e-4 and report.max_cov_diff < 1e-3
        sizes[sigma] = path.stat().st_size
        ort = OnnxModel(path)
        assert ort.info.profile == model.profile
        text = ort.session.get_modelmeta().custom_metadata_map["radar_odom.profile"]
        assert ("feature_radial_blur_px" in text) == (sigma > 0)  # written only when used
        # the stream state is the features' spectrum: the blurred features themselves agree
        cur, state = example_inputs(model, "stream", seed=5)
        out = ort.run({"cart": cur.numpy(), "prev_state": state.numpy()})
        with torch.no_grad():
            _, _, torch_state = model.stream_step(cur, state)
        scale = float(torch_state.abs().max())
        assert np.abs(out["state"] - torch_state.numpy()).max() <= 1e-4 * scale
    # the a, b, c maps are computed in the graph, not stored (3 W×W float32 tables): the file holds
    # one W×W table, |p|², that the exporter folds from two W-vectors (`radial_blur_images`)
    assert sizes[1.0] - sizes[0.0] < 1.5 * w * w * 4

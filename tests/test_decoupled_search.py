"""The decoupled search (Fast-MbyM): a known rotation and translation recovered, the single
rotation against grid_sample, the graph against its numpy-FFT reference and against
onnxruntime, gradients through both stages, interchangeable states, bad settings refused, and
`radar-odom export NAME` reproducing the shipped search."""
import math
from types import SimpleNamespace

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from test_fast_search import pair_with_pose  # noqa: E402

from radar_odom.latency.reference import DecoupledReference, make_reference  # noqa: E402
from radar_odom.profiles import GridProfile  # noqa: E402
from radar_odom_export import onnx_export  # noqa: E402
from radar_odom_export.correlation import rotate_images, rotation_grids  # noqa: E402
from radar_odom_export.decoupled_search import (  # noqa: E402
    CropRotation,
    DecoupledPairStep,
    DecoupledSettings,
    DecoupledStreamStep,
    RingCorrelation,
)
from radar_odom_export.fast_search import FastStreamStep  # noqa: E402
from radar_odom_export.model import MaskedCorrelator  # noqa: E402
from radar_odom_export.onnx_export import export_decoupled, search_metadata  # noqa: E402

pytestmark = pytest.mark.torch

SMALL = dict(resolution_m=1.0, width_px=64, max_translation_m=6.0, rotation_range_rad=math.radians(10),
             rotation_step_rad=math.radians(1), unet_base_channels=4, unet_depth=2)
SETTINGS = DecoupledSettings(radii=24)


def small_profile(**kw):
    """W = 64, n = 6, yaw ±10° in 1° steps (A = 180 angles over 180°)."""
    return GridProfile("small", **{**SMALL, **kw})


def step_for(profile, masking="raw", settings=SETTINGS, seed=0):
    torch.manual_seed(seed)
    return DecoupledStreamStep(MaskedCorrelator(profile, masking=masking).eval(), settings).eval()


@pytest.mark.parametrize("pose", [(1.0, -0.5, math.radians(4.3)), (-1.5, 1.0, math.radians(-7.6)),
                                  (0.5, 0.0, 0.0)])
def test_a_known_rotation_and_translation_are_recovered(pose):
    # 128 px at 0.5 m (64 px images hold too few rings' worth of angular detail: up to 0.6° off)
    profile = small_profile(width_px=128, resolution_m=0.5, max_translation_m=3.0)
    step = step_for(profile, settings=DecoupledSettings(radii=32))
    prev, cur = pair_with_pose(pose, 128, 0.5, count=40, radius_m=9, seed=1)
    prev, cur = torch.from_numpy(prev)[None], torch.from_numpy(cur)[None]
    with torch.no_grad():
        state = step.model.initial_state(prev)
        yaw, _, _ = step.rings(state, step.model.initial_state(cur))
        est, cov, _ = step(cur, state)
    # the rotation stage alone: sub-bin (1° bins), sign as the pose's
    assert abs(yaw.item() - pose[2]) < math.radians(0.1)
    assert abs(est[0, 2].item() - pose[2]) < math.radians(0.1)
    # the translation at that yaw, to the cell (β = 1 on raw blobs reads the best cell)
    np.testing.assert_allclose(est[0, :2].numpy(), pose[:2], atol=0.26)
    assert torch.all(torch.linalg.eigvalsh(cov[0]) > 0)


def test_the_single_rotation_is_the_bilinear_grid_sample_rotation_inside_the_disc():
    profile = small_profile()
    model = MaskedCorrelator(profile, masking="raw")
    images = torch.rand(3, 64, 64) * model.support  # zero outside the support disc, as features are
    yaw = torch.tensor([0.13, -0.05, 0.0])
    got = CropRotation(64, profile.translation_cells)(images, yaw)
    want = torch.cat([rotate_images(images[i:i + 1], rotation_grids(yaw[i:i + 1], 64))[:, 0] for i in range(3)])
    assert (got - want).abs().max() < 1e-5


def test_the_graph_matches_its_numpy_fft_reference():
    """Pose and covariance of the torch step (matmul DFTs, gathers) against the numpy search
    (pocketfft, numpy bilinear) that `radar-odom profile` times, on random sparse features."""
    profile = small_profile(beta_pose=0.05, beta_cov=0.05)
    step = step_for(profile)
    ref = make_reference(profile, search_metadata(step))
    assert isinstance(ref, DecoupledReference)
    g = torch.Generator().manual_seed(3)
    for _ in range(3):
        prev, cur = torch.rand(2, 1, 64, 64, generator=g) ** 6
        with torch.no_grad():
            state = step.model.initial_state(prev)
            pose, cov, new_state = step(cur, state)
            features = step.model.sweep_features(cur)
        spec = state[0, 0].double().numpy() + 1j * state[0, 1].double().numpy()
        ref_pose, ref_cov = ref.search(spec, features[0].numpy())
        np.testing.assert_allclose(pose[0].numpy(), ref_pose, atol=2e-4)
        np.testing.assert_allclose(cov[0].numpy(), ref_cov, rtol=2e-3, atol=1e-7)
        ref_yaw, _, ref_cos = ref.yaw(spec, np.fft.rfft2(features[0].numpy().astype(np.float64)))
        _, _, cosine = step.rings(state, new_state)
        np.testing.assert_allclose(cosine[0].numpy(), ref_cos, atol=1e-4)


def test_export_has_no_dft_node_and_onnxruntime_matches_torch(tmp_path):
    from radar_odom.onnx_model import OnnxModel

    step = step_for(small_profile(), masking="learned")
    path = tmp_path / "decoupled.onnx"
    report = export_decoupled(step.model, path, SETTINGS)  # verify=True: ORT vs torch on fresh inputs
    assert report.max_pose_diff < 1e-4 and report.max_cov_diff < 1e-3
    assert not {"DFT", "STFT"} & set(report.ops)
    assert "decoupled search" in report.summary().splitlines()[0]
    info = OnnxModel(path).info
    assert info.search["kind"] == "decoupled" and info.search["radii"] == SETTINGS.radii
    # a second stream step through the state the graph itself returned
    ort_model = OnnxModel(path, threads=1)
    g = torch.Generator().manual_seed(7)
    sweeps = torch.rand(3, 1, 64, 64, generator=g) ** 6
    state_t = step.model.initial_state(sweeps[0]).detach()
    state_o = state_t.numpy()
    for k in (1, 2):
        with torch.no_grad():
            pose_t, cov_t, state_t = step(sweeps[k], state_t)
        out = ort_model.run({"cart": sweeps[k].numpy(), "prev_state": state_o})
        state_o = out["state"]
        np.testing.assert_allclose(out["pose"], pose_t.numpy(), atol=1e-4)
        np.testing.assert_allclose(out["covariance"], cov_t.numpy(), rtol=1e-3, atol=1e-7)


def test_the_gradient_reaches_the_masker_through_both_stages():
    """The yaw comes from the ring correlation only and x, y from the translation correlation:
    a loss on either reaches the masker's weights."""
    step = step_for(small_profile(), masking="learned").train()
    pair = DecoupledPairStep(step)
    prev, cur = pair_with_pose((2.0, -1.0, math.radians(4.3)), 64, 1.0, count=40, radius_m=18, seed=2)
    prev, cur = torch.from_numpy(prev)[None], torch.from_numpy(cur)[None]
    first = step.model.masker.parameters().__next__()
    for axis in (2, 0, 1):  # yaw (rotation stage), x, y (translation stage)
        step.model.zero_grad()
        pose, _ = pair(prev, cur)
        pose[0, axis].backward()
        grads = [p.grad for p in step.model.masker.parameters() if p.grad is not None]
        assert grads and torch.isfinite(first.grad).all()
        assert sum(float(g.abs().sum()) for g in grads) > 0, f"no gradient from pose axis {axis}"


def test_states_are_interchangeable_with_the_fast_and_exhaustive_steps():
    profile = small_profile()
    torch.manual_seed(0)
    model = MaskedCorrelator(profile, masking="learned").eval()
    cur = torch.rand(1, 64, 64) ** 6
    prev_state = model.initial_state(torch.rand(1, 64, 64) ** 6)
    with torch.no_grad():
        _, _, dec = DecoupledStreamStep(model, SETTINGS)(cur, prev_state)
        _, _, fast = FastStreamStep(model)(cur, prev_state)
        exhaustive = model.initial_state(cur)
    assert dec.shape == exhaustive.shape == (1, 2, 64, 33)
    assert (dec - fast).abs().max() == 0
    assert (dec - exhaustive).abs().max() < 1e-3 * exhaustive.abs().max()


def test_bad_settings_and_models_are_refused():
    with pytest.raises(ValueError, match="radii"):
        DecoupledSettings(radii=0)
    with pytest.raises(ValueError, match="radius_min"):
        DecoupledSettings(radius_min=0.6, radius_max=0.5)
    with pytest.raises(ValueError, match="beta_yaw"):
        DecoupledSettings(beta_yaw=0)
    with pytest.raises(ValueError, match="does not divide 180"):
        RingCorrelation(small_profile(rotation_step_rad=math.radians(0.7)), SETTINGS)
    with pytest.raises(ValueError, match="90"):
        RingCorrelation(small_profile(rotation_range_rad=math.radians(100), rotation_step_rad=math.radians(5)),
                        SETTINGS)
    dual = MaskedCorrelator(small_profile(mode="dual"), masking="learned")
    with pytest.raises(ValueError, match="single-mode"):
        DecoupledStreamStep(dual)
    with pytest.raises(onnx_export.ExportError, match="stream form"):
        onnx_export.export_checkpoint("unused.pt", "x.onnx", form="pair", search="decoupled")


def test_export_by_shipped_name_reproduces_the_shipped_search(monkeypatch, capsys):
    """`radar-odom export cart-0.4` exports with the shipped file's search, settings and form
    (its metadata), unless --search says otherwise."""
    from radar_odom.commands.cli import main
    from radar_odom.model_zoo import pretrained, pretrained_names, shipped_export
    from radar_odom.onnx_model import OnnxModel

    if "cart-0.4" not in pretrained_names():
        pytest.skip("this installation ships no cart-0.4 model")
    shipped = OnnxModel(pretrained("cart-0.4")).info
    got = shipped_export("cart-0.4")
    assert got["search"] == {"coarse_to_fine": "fast", "decoupled": "decoupled"}.get(
        (shipped.search or {}).get("kind"), "exhaustive")
    assert got["form"] == shipped.form
    if shipped.search:
        assert all(got["settings"][k] == v for k, v in shipped.search.items() if k not in ("kind", "band_rotations"))
    asked = []
    monkeypatch.setattr(onnx_export, "export_checkpoint",
                        lambda ckpt, out, **kw: asked.append(kw) or SimpleNamespace(summary=lambda: "ok"))
    assert main(["export", "cart-0.4", "-o", "unused.onnx"]) == 0
    assert main(["export", "cart-0.4", "-o", "unused.onnx", "--search", "exhaustive"]) == 0
    assert asked[0]["search"] == got["search"] and asked[0]["form"] == got["form"]
    assert asked[0].get("search_settings") == got["settings"]
    assert asked[1]["search"] == "exhaustive" and "search_settings" not in asked[1]


def test_the_decoupled_search_is_retired_from_the_cli(capsys):
    """docs/latency.md: 0.58x the fast step and 27 % less accurate, so `radar-odom export` and
    `radar-odom profile` no longer offer it (the library keeps `export_decoupled`)."""
    from radar_odom.commands.cli import main

    for argv in (["export", "cart-0.4", "-o", "unused.onnx", "--search", "decoupled"],
                 ["profile", "--search", "decoupled"]):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
        assert "invalid choice: 'decoupled'" in capsys.readouterr().err


def test_training_through_the_decoupled_search_reduces_the_pose_loss():
    """`radar-odom train --search decoupled`: the objective's pose is the decoupled step's, and a
    few Adam steps on a fixed toy batch lower its loss; the cross-entropy loss is refused."""
    from radar_odom_export import data as D
    from radar_odom_export.train import Objective

    torch.manual_seed(0)
    profile = small_profile(beta_pose=10.0)
    ds = D.PairDataset([D.toy_drive(profile, 5, 9, num_followers=40)])
    items = [ds[i] for i in range(len(ds))]
    batch = {k: torch.as_tensor(np.stack([it[k] for it in items])) for k in items[0]}
    obj = Objective(MaskedCorrelator(profile), "pose", 1.0, "mse", search="decoupled")
    opt = torch.optim.Adam(obj.parameters(), lr=3e-3)
    losses = []
    for _ in range(10):
        loss, _ = obj(batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < losses[0], losses
    with pytest.raises(ValueError, match="pose-loss mse"):
        Objective(MaskedCorrelator(profile), "pose", 1.0, "ce", search="decoupled")

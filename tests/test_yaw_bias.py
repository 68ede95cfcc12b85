"""The straight-road yaw bias (issue 41): the search is not its cause (a pure translation of a sweep
reads no yaw; the search after the masker is mirror-equivariant), the learned masker's handedness is,
and a left/right symmetric masker (`radar_odom_export.symmetry`) removes it; the mirrored world of
`benchmarks/yaw_bias.py` mirrors the drive."""
import math

import numpy as np
import pytest

import radar_odom
from radar_odom.odometry.sweep_input import SweepMotion, graph_input
from radar_odom.onnx_model import OnnxModel

from fixtures import load_script

SEED = 41  # a test's drive, not a comparison


def _bench():
    return load_script("benchmarks/yaw_bias.py")


@pytest.fixture(scope="module")
def frozen_frames():
    """A straight urban drive at 10 m/s, sweeps frozen in time (no motion distortion), past its ramp."""
    return list(_bench().simulator_class(frozen=True)(SEED, 8, _bench_scenario()))[5:]


def _bench_scenario():
    return load_script("benchmarks/scorecard.py").bend_scenario(0.0)


def _mirror_cart(x: np.ndarray) -> np.ndarray:
    """A Cartesian graph input reflected left/right (y → −y): columns reversed about the centre."""
    return np.ascontiguousarray(x[..., ::-1])


# ------------------------------------------------------------------ the implementation reads no yaw
@pytest.mark.parametrize("name", ["cart-0.4"])
def test_a_pure_forward_shift_of_one_sweep_reads_no_yaw(name, frozen_frames):
    """One sweep matched against itself drawn 2.5 m ahead or behind (a straight road's step at 10 m/s):
    the same content, no rotation. The shipped graph reads a yaw two orders below the straight-road bias
    it shows between consecutive sweeps (−0.03 … −0.05 °/sweep, benchmarks/yaw_bias.py)."""
    bench = _bench()
    m = OnnxModel(radar_odom.pretrained(name), threads=1)
    yaws = []
    for f in frozen_frames:
        ref = graph_input(f.scan, m.info)
        for dx in (2.5, -2.5):
            yaws.append(bench.pair_yaw_rad(m, ref, graph_input(f.scan, m.info, SweepMotion(frame_pose=(dx, 0.0, 0.0)))))
    yaws_deg = np.degrees(yaws)
    assert np.max(np.abs(yaws_deg)) < 0.03, yaws_deg
    assert abs(float(np.mean(yaws_deg))) < 0.01, yaws_deg


def test_the_mirrored_world_mirrors_the_drive():
    """`simulator_class(mirror=True)`: the true poses are the reflected ones (y and yaw change sign),
    and a frozen sweep of the mirrored world is the mirror image of the world's sweep (same geometry;
    the noise differs, drawn per row in the scan's own order)."""
    bench = _bench()
    scen = _bench_scenario()
    a = list(bench.simulator_class(frozen=True)(SEED, 3, scen))
    b = list(bench.simulator_class(frozen=True, mirror=True)(SEED, 3, scen))
    for fa, fb in zip(a[1:], b[1:]):
        np.testing.assert_allclose(fb.pose_rel, fa.pose_rel * np.array([1.0, -1.0, -1.0]), atol=1e-12)
    info = OnnxModel(radar_odom.pretrained("cart-0.4"), threads=1).info
    img_a = graph_input(a[2].scan, info)[0]
    img_b = graph_input(b[2].scan, info)[0]
    corr = lambda u, v: float(np.corrcoef(u.ravel(), v.ravel())[0, 1])  # noqa: E731
    # measured on this seed: 0.74 against the mirror image (noise and clutter differ), 0.43 against itself
    assert corr(img_b, _mirror_cart(img_a)) > max(0.65, corr(img_b, img_a) + 0.2)
    # and `mirrored_scan` reflects a sweep the same way the graph input's columns are reversed
    img_m = graph_input(bench.mirrored_scan(a[2].scan), info)[0]
    assert corr(img_m, _mirror_cart(img_a)) > 0.99


# ------------------------------------------------------------------ torch: where the handedness lives
def _step(torch, masking: str, symmetric: bool = False, mirror_average: bool = False):
    from radar_odom_export.checkpoint import model_from_dict, read_checkpoint_dict, resolve_checkpoint
    from radar_odom_export.fast_search import FastStreamStep
    from radar_odom_export.model import MaskedCorrelator
    from radar_odom_export.symmetry import mirror_averaged_checkpoint, mirror_symmetric_checkpoint

    ckpt = read_checkpoint_dict(resolve_checkpoint("cart-0.4"))
    if mirror_average:
        ckpt = mirror_averaged_checkpoint(ckpt)
    if masking == "learned":
        model = model_from_dict(mirror_symmetric_checkpoint(ckpt) if symmetric else ckpt)
    else:  # the shipped profile (cubic rotation, high-pass 12 px), mask ≡ 1
        from radar_odom.profiles import GridProfile

        model = MaskedCorrelator(GridProfile.from_dict(ckpt["profile"]), masking=masking).eval()
    return FastStreamStep(model).eval()


def _pair_pose(torch, step, prev: np.ndarray, cur: np.ndarray) -> np.ndarray:
    p = step.profile
    with torch.no_grad():
        _, _, state = step(torch.from_numpy(prev), torch.zeros(1, 2, p.width_px, p.width_px // 2 + 1))
        pose, _, _ = step(torch.from_numpy(cur), state)
    return pose[0].double().numpy()


def _mirror_sums(torch, step, frames) -> np.ndarray:
    """Per consecutive pair: the pose plus the mirrored pair's pose reflected back, (x − x', y + y', yaw + yaw')."""
    info = OnnxModel(radar_odom.pretrained("cart-0.4"), threads=1).info
    x = [graph_input(f.scan, info) for f in frames]
    out = []
    for prev, cur in zip(x[:-1], x[1:]):
        a = _pair_pose(torch, step, prev, cur)
        b = _pair_pose(torch, step, _mirror_cart(prev), _mirror_cart(cur))
        out.append([a[0] - b[0], a[1] + b[1], a[2] + b[2]])
    return np.array(out)


@pytest.mark.torch
@pytest.mark.slow
def test_the_search_after_the_masker_is_mirror_equivariant(frozen_frames):
    """Normalisation, high-pass, cubic polar rotation, coarse pick and read-out with the mask ≡ 1:
    a pair reflected left/right reads (x, −y, −yaw) to float precision (1e-5 rad = 0.0006°, against a
    bias of 5e-4 rad)."""
    torch = pytest.importorskip("torch")
    sums = _mirror_sums(torch, _step(torch, "raw"), frozen_frames)
    np.testing.assert_allclose(sums[:, 2], 0.0, atol=1e-5)
    np.testing.assert_allclose(sums[:, :2], 0.0, atol=1e-3)  # metres: a thousandth of a pixel is float noise


@pytest.mark.torch
@pytest.mark.slow
def test_the_shipped_masker_is_handed_and_a_symmetric_one_is_not(frozen_frames):
    """The shipped U-Net reads a pair and its mirror image with yaws that do not cancel (its handedness:
    the straight-road bias); with every kernel averaged with its column flip the masks commute with the
    mirror and so does the whole step."""
    torch = pytest.importorskip("torch")
    shipped = _mirror_sums(torch, _step(torch, "learned"), frozen_frames)  # two pairs
    assert np.max(np.abs(shipped[:, 2])) > 1e-4  # ≥ 0.006°: the masker is handed
    sym_step = _step(torch, "learned", symmetric=True)
    sym = _mirror_sums(torch, sym_step, frozen_frames)
    np.testing.assert_allclose(sym[:, 2], 0.0, atol=1e-5)
    # the masks themselves commute with the mirror
    info = OnnxModel(radar_odom.pretrained("cart-0.4"), threads=1).info
    x = torch.from_numpy(graph_input(frozen_frames[0].scan, info))
    with torch.no_grad():
        m = sym_step.model.mask(x)
        m_mirror = sym_step.model.mask(x.flip(-1))
    torch.testing.assert_close(m_mirror, m.flip(-1), atol=1e-4, rtol=0)  # float32 noise: ~1e-5


@pytest.mark.torch
@pytest.mark.slow
def test_the_shipped_masker_averaged_over_the_mirror_is_mirror_equivariant(frozen_frames):
    """`GridProfile.mask_mirror_average` on the shipped cart-0.4, weights as shipped: the masks are
    (M(x) + flip(M(flip(x)))) / 2, so they commute with the mirror and a reflected pair reads
    (x, −y, −yaw) to float precision, as with the mask ≡ 1 — where the same weights without the
    average are handed (`test_the_shipped_masker_is_handed_and_a_symmetric_one_is_not`)."""
    torch = pytest.importorskip("torch")
    step = _step(torch, "learned", mirror_average=True)
    assert step.profile.mask_mirror_average
    sums = _mirror_sums(torch, step, frozen_frames[:2])  # one pair: the shipped weights are handed on each
    np.testing.assert_allclose(sums[:, 2], 0.0, atol=1e-5)
    np.testing.assert_allclose(sums[:, :2], 0.0, atol=1e-3)
    info = OnnxModel(radar_odom.pretrained("cart-0.4"), threads=1).info
    x = torch.from_numpy(graph_input(frozen_frames[0].scan, info))
    with torch.no_grad():
        m, m_mirror = step.model.mask(x), step.model.mask(x.flip(-1))
    torch.testing.assert_close(m_mirror, m.flip(-1), atol=1e-4, rtol=0)  # float32 noise: ~2e-5


@pytest.mark.torch
def test_without_the_mirror_average_the_shipped_masker_runs_as_it_did():
    """The flag off (the shipped profile, and every file made before the field): the profile text, and
    so the shipped file's digest, is what it was, and the masks are the U-Net's own, bit for bit; the
    checkpoint with the flag differs only there, and its masks are the mirror average."""
    torch = pytest.importorskip("torch")
    from radar_odom.model_file import profile_digest
    from radar_odom_export.checkpoint import model_from_dict, read_checkpoint_dict, resolve_checkpoint
    from radar_odom_export.symmetry import mirror_averaged_checkpoint

    shipped = OnnxModel(radar_odom.pretrained("cart-0.4"), threads=1)
    text = shipped.info.profile.to_metadata()["radar_odom.profile"]
    assert not shipped.info.profile.mask_mirror_average and "mask_mirror_average" not in text
    assert profile_digest(text) == shipped.session.get_modelmeta().custom_metadata_map["radar_odom.profile_sha256"]
    ckpt = read_checkpoint_dict(resolve_checkpoint("cart-0.4"))
    averaged = mirror_averaged_checkpoint(ckpt)
    keys = set(ckpt["profile"]) | set(averaged["profile"])  # a checkpoint may hold the field as False, or not at all
    assert {k for k in keys if ckpt["profile"].get(k) != averaged["profile"].get(k)} == {"mask_mirror_average"}
    assert averaged["profile"]["mask_mirror_average"] is True and not ckpt["profile"].get("mask_mirror_average", False)
    model, avg_model = model_from_dict(ckpt), model_from_dict(averaged)
    x = torch.rand(1, 1, 128, 128) ** 4  # a 0.4 m/px sweep pooled 2x, as the masker sees it
    with torch.no_grad():
        assert torch.equal(model._unet_mask(x), model.masker(x))
        torch.testing.assert_close(avg_model._unet_mask(x), 0.5 * (model.masker(x) + model.masker(x.flip(-1)).flip(-1)))
    with pytest.raises(ValueError, match="only a learned masker"):
        mirror_averaged_checkpoint({**ckpt, "masking": "raw"})


@pytest.mark.torch
def test_symmetrising_is_a_projection_and_leaves_the_rest_of_the_checkpoint():
    torch = pytest.importorskip("torch")
    from torch import nn

    from radar_odom_export.checkpoint import read_checkpoint_dict, resolve_checkpoint
    from radar_odom_export.symmetry import is_left_right_symmetric, mirror_symmetric_checkpoint, symmetrise_left_right_

    net = nn.Sequential(nn.Conv2d(1, 2, 3, padding=1), nn.ReLU(), nn.Conv2d(2, 1, 3, padding=1))
    assert not is_left_right_symmetric(net)
    assert symmetrise_left_right_(net) == 2 and is_left_right_symmetric(net)
    before = [p.detach().clone() for p in net.parameters()]
    symmetrise_left_right_(net)  # symmetric kernels stay as they are
    for a, b in zip(before, net.parameters()):
        assert torch.equal(a, b)
    x = torch.rand(1, 1, 16, 16)
    torch.testing.assert_close(net(x.flip(-1)), net(x).flip(-1))

    ckpt = read_checkpoint_dict(resolve_checkpoint("cart-0.4"))
    sym = mirror_symmetric_checkpoint(ckpt)
    assert sym["profile"] == ckpt["profile"] and sym.get("calibration") == ckpt.get("calibration")
    assert "masker_symmetry" in sym["train"] and "masker_symmetry" not in (ckpt.get("train") or {})
    changed = [k for k in ckpt["state_dict"] if not torch.equal(ckpt["state_dict"][k], sym["state_dict"][k])]
    assert changed and all(k.startswith("masker.") and k.endswith("weight") for k in changed)
    with pytest.raises(ValueError, match="only a learned masker can be handed"):
        mirror_symmetric_checkpoint({**ckpt, "masking": "raw"})


def test_yaw_bias_refuses_tuning_seeds():
    bench = _bench()
    with pytest.raises(SystemExit):
        bench.main(["--seeds", "5150", "--parts", "world"])
    assert math.isclose(bench.reflect_y(np.array([[1.0, 2.0]]))[0, 1], -2.0)

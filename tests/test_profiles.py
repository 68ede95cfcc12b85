import math

import pytest

from radar_odom.profiles import PROFILES, GridProfile, get_profile


def test_named_profiles_match_the_paper_resolutions():
    assert {PROFILES[n].resolution_m for n in ("cart-0.8", "cart-0.4", "cart-0.2")} == {0.8, 0.4, 0.2}
    for p in PROFILES.values():
        rots = p.rotations_rad
        assert len(rots) == 61  # ±15° at 0.5°, as in the paper
        assert min(rots) == pytest.approx(-math.pi / 12) and max(rots) == pytest.approx(math.pi / 12)
        assert 0.0 in rots


def test_default_window_covers_fast_driving_at_4hz():
    p = get_profile("cart-0.4")
    assert p.translation_cells == 20 and p.num_translations == 41
    assert p.max_translation_m / 0.25 >= 30  # m/s at 4 Hz


def test_paper_window_selectable():
    p = get_profile("cart-0.2", paper_window=True)
    assert p.max_translation_m == 50.0 and p.translation_cells == 250


def test_metadata_round_trip():
    p = get_profile("polar-0.4").with_(beta_cov=2.789)
    assert GridProfile.from_metadata(p.to_metadata()) == p


def test_files_made_before_rotation_identity_read_as_exact():
    """A profile dict without the key (every file made before it existed) keeps its meaning."""
    d = {k: v for k, v in get_profile("cart-0.4").__dict__.items() if k != "rotation_identity"}
    assert GridProfile.from_dict(d).rotation_identity == "exact"
    p = get_profile("cart-0.4").with_(rotation_identity="resampled")
    assert GridProfile.from_metadata(p.to_metadata()).rotation_identity == "resampled"


def test_the_mirror_average_is_written_only_when_on_and_needs_a_cartesian_input():
    """`GridProfile.mask_mirror_average`: files without the key read False (the masker as it always
    ran) and write the same text as before the field existed; True round-trips through the metadata."""
    p = get_profile("cart-0.4")
    assert not p.mask_mirror_average and "mask_mirror_average" not in p.to_metadata()["radar_odom.profile"]
    q = p.with_(mask_mirror_average=True)
    assert GridProfile.from_metadata(q.to_metadata()) == q and q != p
    with pytest.raises(ValueError, match="mask_mirror_average"):
        get_profile("polar-0.4").with_(mask_mirror_average=True)


def test_bad_profiles_are_rejected():
    with pytest.raises(ValueError, match="rotation_identity"):
        GridProfile("x", resolution_m=1.0, width_px=32, rotation_identity="nearest")
    with pytest.raises(ValueError, match="window"):
        GridProfile("x", resolution_m=1.0, width_px=32, max_translation_m=40)
    with pytest.raises(KeyError, match="unknown profile"):
        get_profile("cart-0.3")

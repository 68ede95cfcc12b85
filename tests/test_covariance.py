"""`radar_odom.covariance`: the post-graph covariance correction and its fit (numpy only)."""
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radar_odom.covariance import (
    CovarianceCorrection,
    correct_covariance,
    corrected_from_eigen,
    fit_correction,
    moment_eigen,
    window_moment_cap,
)
from radar_odom.profiles import get_profile

CELL = (0.8, 0.8, np.pi / 360)
G = 1.0 / 12.0  # the graph's floor, cells² (cov_floor_cells = 1)


def graph_cov(rng, n, cell=CELL, big=5.0):
    """Covariances shaped like the graph's: a random PSD moment (cells²) plus the floor, in m/rad."""
    a = rng.normal(size=(n, 3, 3)) * rng.uniform(0.0, big, size=(n, 1, 1)) ** 0.5
    m = a @ np.swapaxes(a, 1, 2) * rng.uniform(0, 1, size=(n, 1, 1))
    d = np.asarray(cell)
    c = (m + G * np.eye(3)) * d[:, None] * d[None, :]
    return 0.5 * (c + np.swapaxes(c, 1, 2))


params_st = st.builds(
    lambda f, s, p, cap, gr: CovarianceCorrection(cell=CELL, floor=f, scale=s, power=p, max_moment=cap,
                                                  floor_growth=gr),
    st.tuples(*[st.floats(1e-4, 1.0)] * 3),
    st.floats(1e-2, 300.0),
    st.floats(0.2, 3.0),
    st.one_of(st.none(), st.floats(0.5, 100.0)),
    st.tuples(*[st.floats(0.0, 10.0)] * 3),
)


@settings(max_examples=60, deadline=None)
@given(params=params_st, seed=st.integers(0, 2**31 - 1))
def test_output_is_symmetric_positive_definite(params, seed):
    cov = graph_cov(np.random.default_rng(seed), 16)
    out = correct_covariance(cov, params)
    assert out.shape == cov.shape and out.dtype == np.float64
    assert np.all(np.isfinite(out))
    np.testing.assert_array_equal(out, np.swapaxes(out, 1, 2))
    # positive definite: at least the floor in every direction (in cells²)
    d = np.asarray(CELL)
    w = np.linalg.eigvalsh(out / d[:, None] / d[None, :])
    assert np.all(w >= min(params.floor) * (1 - 1e-9) - 1e-12)


def test_identity_parameters_give_the_input_back():
    rng = np.random.default_rng(0)
    cov = graph_cov(rng, 200)
    ident = CovarianceCorrection.identity(CELL)
    assert ident.is_identity
    np.testing.assert_array_equal(correct_covariance(cov, ident), cov)
    # the full path (eigen-decomposition and back) reproduces it but for the round-off
    # allowance: (1e-3 cell)² taken off each moment eigenvalue
    lam, v = moment_eigen(cov, ident)
    d = np.asarray(CELL)
    np.testing.assert_allclose(corrected_from_eigen(lam, v, ident), cov, rtol=0, atol=1.01e-6 * d.max() ** 2)
    # a single 3×3 works the same
    np.testing.assert_array_equal(correct_covariance(cov[0], ident), cov[0])


def test_hand_computed_case():
    cell = (0.5, 0.5, 0.01)
    d = np.array(cell)
    # moment: 4 cells² along x only, plus the graph's floor
    cov = np.diag([G + 4.0, G, G]) * np.outer(d, d)
    p = CovarianceCorrection(cell=cell, floor=(0.01, 0.02, 0.03), scale=2.0, power=0.5)
    # x: 0.01 + 2·4^0.5 = 4.01 cells² = 4.01·0.25 m²; y: 0.02·0.25; yaw: 0.03·1e-4
    # (exactly: 4 − 1e-6, the round-off allowance, under the power)
    x = 0.01 + 2.0 * (4.0 - 1e-6) ** 0.5
    assert x == pytest.approx(4.01, abs=1e-6)
    np.testing.assert_allclose(correct_covariance(cov, p), np.diag([x * 0.25, 0.02 * 0.25, 0.03e-4]), rtol=1e-12,
                               atol=1e-15)
    # the cap bounds the moment term; the floor growth multiplies the floor by (1 + g·λ₁) = 5
    p2 = CovarianceCorrection(cell=cell, floor=(0.01, 0.02, 0.03), scale=2.0, power=0.5, max_moment=3.0,
                              floor_growth=(1.0, 0.0, 1.0))
    np.testing.assert_allclose(correct_covariance(cov, p2), np.diag([(0.05 + 3.0) * 0.25, 0.02 * 0.25, 0.15e-4]),
                               rtol=1e-12, atol=1e-15)


def test_eigenbasis_follows_the_moment():
    """A ridge along a direction in the x-y plane is corrected along that direction (equal x, y
    cells and floors: the correction commutes with a rotation of the plane)."""
    p = CovarianceCorrection(cell=CELL, floor=(0.02, 0.02, 0.05), scale=3.0, power=1.5)
    d = np.asarray(CELL)
    th = 0.7
    r = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    m = np.diag([2.0, 0.1, 0.0])
    cov = (r @ m @ r.T + G * np.eye(3)) * np.outer(d, d)
    e = 1e-6  # round-off allowance
    moment = r @ np.diag([3.0 * (2.0 - e) ** 1.5, 3.0 * (0.1 - e) ** 1.5, 0.0]) @ r.T
    want = (moment + np.diag([0.02, 0.02, 0.05])) * np.outer(d, d)
    np.testing.assert_allclose(correct_covariance(cov, p), want, rtol=1e-10, atol=1e-14)


def test_json_round_trip_and_validation():
    p = CovarianceCorrection(cell=CELL, floor=(0.01, 0.002, 0.06), scale=200.0, power=2.5, max_moment=None,
                             floor_growth=(0.0, 0.0, 1.5), fitted_on={"model": "cart-0.8", "seeds": [2500, 2501]})
    text = p.to_json()
    json.loads(text)  # plain JSON (no NaN / Infinity)
    q = CovarianceCorrection.from_json(text)
    assert q == p and q.fitted_on == p.fitted_on
    with pytest.raises(ValueError):
        CovarianceCorrection(cell=CELL, scale=0.0)
    with pytest.raises(ValueError):
        CovarianceCorrection(cell=(0.8, 0.8))
    with pytest.raises(ValueError):
        CovarianceCorrection.from_dict({**p.to_dict(), "bogus": 1})
    with pytest.raises(ValueError):
        CovarianceCorrection.from_dict({**p.to_dict(), "kind": "other/9"})
    with pytest.raises(ValueError):
        correct_covariance(np.full((3, 3), np.nan), p)


def test_profile_units():
    prof = get_profile("cart-0.8")
    ident = CovarianceCorrection.identity_for(prof)
    assert ident.cell == (prof.resolution_m, prof.resolution_m, prof.rotation_step_rad)
    assert ident.graph_floor == pytest.approx([prof.cov_floor_cells**2 / 12.0] * 3)
    assert ident.matches(prof)
    np.testing.assert_allclose(np.asarray(ident.graph_floor) * np.asarray(ident.cell) ** 2, prof.covariance_floor)


def test_fit_makes_every_group_honest():
    """Two kinds of scene: sharp peaks whose error is far below the graph's floor, and ridges
    whose error is far beyond the graph's moment. One global scale cannot fix both; the fit
    brings mean d² close to 3 in each."""
    rng = np.random.default_rng(1)
    d = np.asarray(CELL)
    n = 1500
    truth = CovarianceCorrection(cell=CELL, floor=(0.01, 0.002, 0.05), scale=6.0, power=1.5)
    covs, errs, groups = [], [], []
    for name, big in (("sharp", 0.01), ("ridge", 4.0)):
        lam = rng.uniform(0, big, n)
        m = np.zeros((n, 3, 3))
        m[:, 0, 0] = lam  # a ridge along x
        cov = (m + G * np.eye(3)) * np.outer(d, d)
        true_cov = correct_covariance(cov, truth)
        e = np.einsum("nij,nj->ni", np.linalg.cholesky(true_cov), rng.normal(size=(n, 3)))
        covs.append(cov)
        errs.append(e)
        groups += [name] * n
    covs, errs = np.concatenate(covs), np.concatenate(errs)
    p, rep = fit_correction(covs, errs, groups, CELL, fit=("floor", "scale", "power"), max_moment=window_moment_cap(10))
    assert rep["before"]["sharp"] < 1.0 and rep["before"]["ridge"] > 6.0
    assert rep["mix_after"] == pytest.approx(3.0, rel=1e-6)
    for g in ("sharp", "ridge"):
        assert 2.6 < rep["after"][g] < 3.4, rep
    # a global scale alone (no free parameter but the final factor) cannot do that
    _, rep0 = fit_correction(covs, errs, groups, CELL, fit=(), init=CovarianceCorrection.identity(CELL))
    assert rep0["after"]["sharp"] < 1.0 and rep0["after"]["ridge"] > 5.0

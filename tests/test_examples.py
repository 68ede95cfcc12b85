"""The example scripts that ship with the repository run, and their maths is right."""

import numpy as np
import pytest

from fixtures import load_script


def _load(name):
    return load_script(f"examples/{name}.py")


def test_ellipse_points_lie_on_the_chi2_contour():
    ell = _load("covariance_ellipses")
    cov = np.array([[0.5, 0.2], [0.2, 0.1]])
    pts = ell.ellipse_xy(cov, d2=ell.CHI2_2DOF_95)
    d2 = np.einsum("pi,ij,pj->p", pts, np.linalg.inv(cov), pts)
    np.testing.assert_allclose(d2, ell.CHI2_2DOF_95, rtol=1e-9)
    # the extent along an axis is sqrt(d2 · variance)
    assert pts[:, 0].max() == pytest.approx(np.sqrt(ell.CHI2_2DOF_95 * 0.5), rel=1e-2)


@pytest.mark.slow
def test_covariance_ellipses_example_draws_a_held_out_drive(tmp_path, capsys):
    ell = _load("covariance_ellipses")
    out = tmp_path / "e.png"
    assert ell.main(["--frames", "10", "--every", "2", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert out.stat().st_size > 10_000
    assert "cart-0.4 on open-5000, 9 steps" in text and "mean d²" in text and "inside its 95 % ellipse" in text

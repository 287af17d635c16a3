"""Modal data, assembly and parameter validation (docs/model.md §2–4)."""

import math

import numpy as np
import pytest

from worker.model import (
    CellParams,
    assemble,
    betas,
    mode_means,
    mode_shape,
    rayleigh_constants,
    tip_values,
)

# Gauss–Legendre on [0, 1]: exact for polynomials of degree < 1600, ample for 30 modes.
_X, _WQ = np.polynomial.legendre.leggauss(800)
_X = 0.5 * (_X + 1.0)
_WQ = 0.5 * _WQ


def _quad(f: np.ndarray) -> float:
    return float(np.sum(_WQ * f))


def test_betas_solve_frequency_equation_and_match_known_values():
    b = betas(30)
    known = [1.8751040687, 4.6940911330, 7.8547574382, 10.9955407349, 14.1371683910]
    np.testing.assert_allclose(b[:5], known, rtol=1e-10)
    # cos β cosh β = -1, written without overflow.
    np.testing.assert_allclose(np.cos(b) + 1.0 / np.cosh(b), 0.0, atol=1e-14)
    np.testing.assert_allclose(b[10:], (np.arange(11, 31) - 0.5) * math.pi, rtol=1e-12)
    # The i-th root lies within 0.31 of (i - 1/2)π: none skipped, none repeated.
    assert np.all(np.abs(b - (np.arange(1, 31) - 0.5) * math.pi) < 0.31)


def test_tip_values_and_means_match_model_md():
    np.testing.assert_array_equal(tip_values(4), [2.0, -2.0, 2.0, -2.0])
    np.testing.assert_allclose(
        mode_means(5), [0.78299, 0.43394, 0.25443, 0.18190, 0.14147], atol=5e-6
    )


@pytest.mark.parametrize("i", [1, 2, 5, 12, 20, 30])
def test_closed_forms_agree_with_quadrature_of_cancellation_free_shape(i):
    phi = mode_shape(i, _X)
    phi2 = mode_shape(i, _X, derivative=2)
    b = betas(i)[-1]
    assert _quad(phi * phi) == pytest.approx(1.0, rel=1e-10)
    assert _quad(phi) == pytest.approx(mode_means(i)[-1], rel=1e-9, abs=1e-12)
    assert _quad(phi2 * phi2) == pytest.approx(b**4, rel=1e-9)
    assert float(mode_shape(i, 1.0)) == pytest.approx(tip_values(i)[-1], rel=1e-10)
    assert abs(float(mode_shape(i, 0.0))) < 1e-12  # clamped


def test_modes_are_orthogonal_up_to_30():
    shapes = np.array([mode_shape(i, _X) for i in range(1, 31)])
    gram = (shapes * _WQ) @ shapes.T
    np.testing.assert_allclose(gram, np.eye(30), atol=1e-9)


def test_naive_textbook_shape_loses_digits_for_high_modes():
    # Why the cancellation-free form exists: the textbook form is wrong at the tip for n = 30.
    b = betas(30)[-1]
    s = (np.sinh(b) - np.sin(b)) / (np.cosh(b) + np.cos(b))
    naive_tip = np.cosh(b) - np.cos(b) - s * (np.sinh(b) - np.sin(b))
    assert abs(naive_tip - (-2.0)) > 1.0
    assert float(mode_shape(30, 1.0)) == pytest.approx(-2.0, rel=1e-12)


def test_assembly_paper_and_full():
    p = CellParams(theta=0.3, sigma=0.05, gamma_s=2.0, gamma_r=1.0, xi=0.05, modes=3)
    s = assemble(p)
    d = mode_means(3)
    np.testing.assert_allclose(s.M[:3, 3], -d)
    assert s.M[3, 3] == pytest.approx(1 / 0.3)
    np.testing.assert_array_equal(s.M[3, :3], 0.0)
    np.testing.assert_array_equal(s.X, [2, -2, 2, 1])
    np.testing.assert_array_equal(s.W, [2, -2, 2, 0])
    assert s.K[3, 3] == pytest.approx(1 / (0.3 * 4.0))
    assert s.C[3, 3] == pytest.approx(2 * 0.05 / (0.3 * 2.0))
    assert s.f_sin == pytest.approx(0.5) and s.f_cos == pytest.approx(0.1)
    assert s.G > 0

    f = assemble(CellParams(theta=0.3, sigma=0.05, gamma_s=2.0, gamma_r=1.0, coupling="full"))
    np.testing.assert_allclose(f.M, f.M.T)
    assert np.all(np.linalg.eigvalsh(f.M) > 0)
    assert f.M[-1, -1] == pytest.approx(1 / 0.3 + 1)
    np.testing.assert_array_equal(f.X, f.W)
    assert f.kappa == pytest.approx(1.3) and s.kappa == 1.0


def test_a_cells_matrices_are_assembled_once_and_only_for_that_cell():
    base = dict(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05, modes=4)
    a = assemble(CellParams(gamma_r=1.0, **base))
    b = assemble(CellParams(gamma_r=2.5, g1=0.7, **base))  # γ_r and the gaps: the same cell
    assert a.M is b.M and a.C is b.C and a.Minv is b.Minv
    assert a.f_cos != b.f_cos  # the forcing does depend on γ_r
    for change in (dict(theta=0.31), dict(sigma=0.06), dict(gamma_s=1.1), dict(xi=0.06),
                   dict(xi_b=0.01), dict(modes=5), dict(coupling="full")):  # fmt: skip
        c = assemble(CellParams(gamma_r=1.0, **{**base, **change}))
        assert c.M is not a.M, change
        assert not (c.M.shape == a.M.shape and np.array_equal(c.M, a.M)
                    and np.array_equal(c.C, a.C) and np.array_equal(c.K, a.K)), change  # fmt: skip
    # -0.0 == 0.0 as a number, but a damping of -0.0 has its own -0.0 entries
    zero = assemble(CellParams(gamma_r=1.0, **{**base, "xi": 0.0}))
    negz = assemble(CellParams(gamma_r=1.0, **{**base, "xi": -0.0}))
    assert math.copysign(1.0, zero.C[-1, -1]) == 1.0
    assert math.copysign(1.0, negz.C[-1, -1]) == -1.0


def test_rayleigh_damping_gives_xi_b_at_modes_1_and_5():
    p = CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.0, xi=0.05, xi_b=0.02, modes=7)
    s = assemble(p)
    w = betas(7) ** 2 * math.sqrt(0.05)
    zeta = np.diag(s.C)[:7] / (2 * w)
    assert zeta[0] == pytest.approx(0.02) and zeta[4] == pytest.approx(0.02)
    assert zeta[6] > 0.02  # stiffness-proportional part grows with frequency
    a, b = rayleigh_constants(w[:1], 0.02)
    assert a == pytest.approx(2 * 0.02 * w[0]) and b == 0.0
    assert s.C[-1, -1] == pytest.approx(2 * 0.05 / 0.3)  # mass keeps ξ


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("theta", 0.0, "theta must be > 0, got 0.0"),
        ("sigma", -1.0, "sigma must be > 0, got -1.0"),
        ("gamma_s", float("nan"), "gamma_s must be finite, got nan"),
        ("gamma_r", float("inf"), "gamma_r must be finite, got inf"),
        ("xi", -0.1, "xi must be >= 0, got -0.1"),
        ("g1", -0.1, "g1 must be >= 0, got -0.1"),
        ("g2", float("nan"), "g2 must be finite"),
        ("xi_b", -1.0, "xi_b must be >= 0"),
        ("modes", 0, "modes must be an integer in 1…30, got 0"),
        ("modes", 31, "modes must be an integer in 1…30, got 31"),
        ("modes", 2.5, "modes must be an integer"),
        ("coupling", "weird", "coupling must be one of paper, full, got 'weird'"),
        ("theta", "a", "theta must be a real number, got 'a'"),
    ],
)
def test_bad_parameters_name_field_value_and_range(field, value, message):
    kw = dict(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.0)
    kw[field] = value
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        CellParams(**kw)

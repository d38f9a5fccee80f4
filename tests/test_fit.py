"""Tests of ident.identify.fit: truth round trips (known transfer functions -> FRF -> fit ->
poles, residues, FRF), weighting, stability, order selection, vector fitting, the
modal conversions, and bad inputs."""

import doctest
import re
import warnings

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import signal

from ident.identify import fit as fitmod
from ident.errors import FitWarning, IdentificationError
from ident.identify.fit import TfFit, VfFit, fit_common_poles, fit_tf, select_order, tf_fits_to_modal

F_HZ = np.linspace(0.5, 20.0, 800)  # the paper's band on a Welch-like grid

RTOL_EXACT = 1e-6  # noise-free data: the fit converges to rounding (~1e-13); margin for the
#                    sensitivity of lightly damped poles and of residues
FIT_ERROR_EXACT = 1e-9  # noise-free relative fit error: rounding only
NOISE = 0.01  # relative complex noise of the noisy cases
DB_NOISY = 0.2  # 1 % noise averaged over 800 points by <= 17 parameters: ~0.02 dB expected
RTOL_MODAL = 1e-10  # two evaluations of the same pole-residue sum: rounding only
RTOL_POLY = 1e-8  # num/den expanded in s (order 6, coefficients over ~1e8): rounding only


# ----------------------------------------------------------------------------------------------
# truth models
# ----------------------------------------------------------------------------------------------


def _pair(f_hz, zeta):
    """Pole pair (Im > 0 member) of natural frequency f_hz and damping ratio zeta."""
    w = 2 * np.pi * f_hz
    return complex(-zeta * w, w * np.sqrt(1 - zeta**2))


def _with_conj(poles):
    out = []
    for p in poles:
        out.append(p)
        if p.imag != 0:
            out.append(np.conj(p))
    return np.array(out, dtype=complex)


class Truth:
    """A transfer function in zero-pole-gain form: K prod(s - z) / prod(s - p)."""

    def __init__(self, zeros, poles, gain):
        self.z = np.asarray(zeros, dtype=complex)
        self.p = np.asarray(poles, dtype=complex)
        self.k = gain

    def response(self, f_hz):
        s = 2j * np.pi * f_hz
        h = self.k * np.ones_like(s)
        for z in self.z:
            h = h * (s - z)
        for p in self.p:
            h = h / (s - p)
        return h

    def residues(self):
        """Residues at the poles (distinct poles), and the direct term."""
        r = np.array([self.k * np.prod(p - self.z) / np.prod(np.delete(p - self.p, i))
                      for i, p in enumerate(self.p)])
        return r, (self.k if self.z.size == self.p.size else 0.0)

    @property
    def n_den(self):
        return self.p.size

    @property
    def n_num(self):
        return self.z.size


def _sorted(p, *others):
    """Sort poles (and arrays aligned with them) by magnitude, then imaginary part."""
    key = np.lexsort((p.imag, np.round(np.abs(p), 6)))
    return (p[key],) + tuple(o[key] for o in others)


TWO_PI = 2 * np.pi
TRUTHS = {
    # shock velocity per force [m/s / N]: one lightly damped pair
    "order2": Truth([0.0], _with_conj([_pair(3.0, 0.05)]), 1e-5),
    # three pairs (heavy, light, medium damping), a lightly damped zero pair near 6 Hz
    "order6-zero": Truth(np.r_[_with_conj([_pair(6.0, 0.05)]),
                               -TWO_PI * np.array([30.0, 60.0, 90.0])],
                         _with_conj([_pair(1.5, 0.3), _pair(4.0, 0.05), _pair(12.0, 0.15)]), 1e-5),
    # tire force per wheel-loader displacement [N/m]: direct term, zero near 6 Hz
    "order8-direct": Truth(_with_conj([_pair(6.0, 0.03), _pair(2.0, 0.5), _pair(10.0, 0.2),
                                       _pair(15.0, 0.1)]),
                           _with_conj([_pair(1.2, 0.4), _pair(3.0, 0.08), _pair(9.0, 0.2),
                                       _pair(16.0, 0.03)]), 1e5),
    # relative degree 2 (numerator order 4 over 6): exercises the numerator constraints
    "order6-reldeg2": Truth(np.r_[_with_conj([_pair(6.0, 0.1)]), -TWO_PI * np.array([0.8, 25.0])],
                            _with_conj([_pair(1.5, 0.3), _pair(4.0, 0.05), _pair(12.0, 0.15)]),
                            0.1),
}


def _assert_close_per_pair(actual, desired, rtol):
    """|actual - desired| <= rtol * max |desired| of each pair (last axis = frequency)."""
    scale = np.abs(desired).max(axis=-1, keepdims=True)
    worst = float(np.max(np.abs(actual - desired) / scale))
    assert worst <= rtol, f"largest error {worst:.3g} of the pair's peak > {rtol:g}"


def _noisy(h, rng, level=NOISE):
    return h * (1 + level * (rng.standard_normal(h.size) + 1j * rng.standard_normal(h.size))
                / np.sqrt(2))


# ----------------------------------------------------------------------------------------------
# fit_tf
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(TRUTHS))
def test_fit_tf_recovers_poles_and_residues(name):
    truth = TRUTHS[name]
    fit = fit_tf(F_HZ, truth.response(F_HZ), n_den=truth.n_den, n_num=truth.n_num)
    r_true, d_true = truth.residues()
    p_true, r_true = _sorted(truth.p, r_true)
    p_fit, r_fit = _sorted(fit.poles, fit.residues)
    assert fit.converged and fit.fit_error < FIT_ERROR_EXACT
    assert_allclose(p_fit, p_true, rtol=RTOL_EXACT)
    assert_allclose(r_fit, r_true, rtol=RTOL_EXACT)
    assert_allclose(fit.direct, d_true, rtol=RTOL_EXACT, atol=RTOL_EXACT * np.abs(r_true).max()
                    / np.abs(p_true).max())
    f_out = np.linspace(0.1, 40.0, 200)  # beyond the fitted band: the model, not just the data
    h_true = truth.response(f_out)
    assert_allclose(fit.evaluate(f_out), h_true, rtol=0, atol=RTOL_EXACT * np.abs(h_true).max())


@pytest.mark.parametrize("name", list(TRUTHS))
def test_fit_tf_with_one_percent_noise_is_within_0p2_db(name, rng):
    truth = TRUTHS[name]
    h = truth.response(F_HZ)
    hn = _noisy(h, rng)
    # relative weighting 1/|h|^2: the noise is relative, so every frequency gets the same
    # error variance (without it, 1 % noise at the peaks swamps the 6 Hz notch)
    fit = fit_tf(F_HZ, hn, weight=1 / np.abs(hn) ** 2, n_den=truth.n_den, n_num=truth.n_num)
    db_error = 20 * np.log10(np.abs(fit.evaluate(F_HZ) / h))
    assert np.max(np.abs(db_error)) < DB_NOISY
    assert 0.8 * NOISE < fit.fit_error < 1.2 * NOISE  # down to the noise, not below (overfit)


def test_polynomial_form_agrees_with_pole_residue_form():
    truth = TRUTHS["order6-zero"]
    fit = fit_tf(F_HZ, truth.response(F_HZ), n_den=6, n_num=5)
    assert fit.num.shape == (6,) and fit.den.shape == (7,) and fit.den[0] == 1.0
    _, h_poly = signal.freqs(fit.num, fit.den, worN=2 * np.pi * F_HZ)
    h = fit.evaluate(F_HZ)
    assert_allclose(h_poly, h, rtol=0, atol=RTOL_POLY * np.abs(h).max())


def test_gauss_newton_minimizes_the_output_error(rng):
    # on noisy data the SK iterate is not the output-error minimum; GN and LM reach the same one
    truth = TRUTHS["order8-direct"]
    hn = _noisy(truth.response(F_HZ), rng)
    gn = fit_tf(F_HZ, hn, n_den=8, n_num=8, method="gauss-newton")
    lm = fit_tf(F_HZ, hn, n_den=8, n_num=8, method="levenberg-marquardt")
    sk = fit_tf(F_HZ, hn, n_den=8, n_num=8, method="sk")
    assert gn.converged and lm.converged and gn.iterations >= 1
    assert gn.fit_error <= sk.fit_error
    assert_allclose(_sorted(lm.poles)[0], _sorted(gn.poles)[0], rtol=1e-6)  # same minimum
    assert len(gn.history) == len(gn.stages) and gn.stages[0] in ("levi", "log-spaced")
    gn_part = [e for e, st in zip(gn.history, gn.stages) if st == "gn"]
    assert np.all(np.diff(gn_part) <= 0)  # step halving: monotone
    assert gn.settings["n_den"] == 8 and gn.settings["method"] == "gauss-newton"


def test_zero_weight_frequencies_are_ignored(rng):
    truth = TRUTHS["order8-direct"]
    h = truth.response(F_HZ)
    w = np.ones(F_HZ.size)
    bad = rng.choice(F_HZ.size, 80, replace=False)
    w[bad] = 0.0
    garbage = h.copy()
    garbage[bad] = 1e9 * (rng.standard_normal(bad.size) + 1j)
    garbage[bad[:5]] = np.nan
    fit = fit_tf(F_HZ, garbage, weight=w, n_den=8, n_num=8)
    ref = fit_tf(F_HZ[w > 0], h[w > 0], n_den=8, n_num=8)
    assert fit.fit_error < FIT_ERROR_EXACT
    assert_allclose(_sorted(fit.poles)[0], _sorted(ref.poles)[0], rtol=1e-12)
    assert_allclose(_sorted(fit.poles)[0], _sorted(truth.p)[0], rtol=RTOL_EXACT)


def test_unstable_truth_warns_and_returns_stable_poles():
    unstable = _pair(5.0, -0.02)  # a slightly unstable 5 Hz pair
    truth = Truth(-TWO_PI * np.array([3.0, 50.0]), _with_conj([_pair(2.0, 0.2), unstable]), 1e-3)
    h = truth.response(F_HZ)
    with pytest.warns(FitWarning) as record:
        fit = fit_tf(F_HZ, h, n_den=4, n_num=2)
    messages = " | ".join(str(w.message) for w in record)
    assert re.search(r"unstable poles reflected: 5(\.0+)? Hz \(damping ratio -0.02\)", messages)
    assert np.all(fit.poles.real < 0)
    assert any("reflected" in note for note in fit.notes)
    # without the constraint the truth is recovered, silently
    with warnings.catch_warnings():
        warnings.simplefilter("error", FitWarning)
        free = fit_tf(F_HZ, h, n_den=4, n_num=2, stable=False)
    assert_allclose(_sorted(free.poles)[0], _sorted(truth.p)[0], rtol=RTOL_EXACT)


def test_no_convergence_warns_and_returns_best_iterate(rng):
    truth = TRUTHS["order8-direct"]
    hn = _noisy(truth.response(F_HZ), rng)
    full = fit_tf(F_HZ, hn, n_den=8, n_num=8)
    assert full.iterations >= 2  # so that one iteration is not enough
    with pytest.warns(FitWarning, match="did not converge in 1 iterations"):
        one = fit_tf(F_HZ, hn, n_den=8, n_num=8, max_iter=1)
    assert not one.converged and one.iterations == 1
    assert one.fit_error >= full.fit_error
    assert one.fit_error <= min(one.history[:-1])  # no worse than its start


@pytest.mark.parametrize("poles", [
    np.r_[-TWO_PI * 3.0, -TWO_PI * 3.0, _with_conj([_pair(8.0, 0.1)])],  # double real pole
    np.r_[_with_conj([_pair(8.0, 0.1)]), _with_conj([_pair(8.0, 0.1)])],  # double pole pair
], ids=["real", "pair"])
def test_repeated_poles_are_split_with_a_note(poles):
    truth = Truth([-TWO_PI * 6.0], poles, 1e3)
    h = truth.response(F_HZ)
    fit = fit_tf(F_HZ, h, n_den=4, n_num=1)
    # a symmetric split by 1e-5 changes the model in second order: (1e-5 / zeta)^2 at most
    assert fit.fit_error < 1e-8
    assert len(set(np.round(fit.poles, 12))) == 4  # distinct, so partial fractions exist
    assert any("repeated pole" in note for note in fit.notes)
    # the large, cancelling residues still evaluate (and realize) accurately
    assert_allclose(fit.to_modal().frequency_response(F_HZ)[0, 0], fit.evaluate(F_HZ), rtol=0,
                    atol=1e-10 * np.abs(h).max())


def test_order_10_fit_keeps_its_accuracy():
    # poles from 0.5 to 25 Hz: s^10 spans ~1e22 over the band in rad/s; the scaled
    # section basis must make this as accurate as the low orders
    poles = _with_conj([_pair(0.5, 0.1), _pair(1.5, 0.2), _pair(4.0, 0.05), _pair(10.0, 0.1),
                        _pair(25.0, 0.05)])
    zeros = np.r_[_with_conj([_pair(6.0, 0.1), _pair(2.5, 0.3), _pair(14.0, 0.2)]),
                  -TWO_PI * np.array([0.8, 40.0, 60.0])]
    truth = Truth(zeros, poles, 1e-5 * (TWO_PI * 25.0) ** 2)
    h = truth.response(F_HZ)
    fit = fit_tf(F_HZ, h, n_den=10, n_num=9)
    assert fit.fit_error < FIT_ERROR_EXACT
    r_true, _ = truth.residues()
    p_true, r_true = _sorted(truth.p, r_true)
    p_fit, r_fit = _sorted(fit.poles, fit.residues)
    assert_allclose(p_fit, p_true, rtol=RTOL_EXACT)
    assert_allclose(r_fit, r_true, rtol=RTOL_EXACT)


# ----------------------------------------------------------------------------------------------
# select_order
# ----------------------------------------------------------------------------------------------


def test_select_order_finds_the_true_order(rng):
    truth = TRUTHS["order6-zero"]
    h = truth.response(F_HZ)
    fit, table = select_order(F_HZ, h, relative_num=-1, stop_early=False)
    assert fit.n_den == 6
    assert [n for n, _ in table] == list(range(2, 11))
    assert dict(table)[6] < FIT_ERROR_EXACT < dict(table)[5]
    # stopping early: the same choice, from the orders up to the chosen one
    fit_e, table_e = select_order(F_HZ, h, relative_num=-1)
    assert fit_e.n_den == 6 and table_e == table[:len(table_e)]
    assert [n for n, _ in table_e] == list(range(2, 7))
    hn = _noisy(h, rng)
    fit_n, table_n = select_order(F_HZ, hn, weight=1 / np.abs(hn) ** 2, relative_num=-1)
    assert 6 <= fit_n.n_den <= 8


def test_select_order_stops_early_only_when_the_choice_is_settled():
    # an order that reaches the floor ends the search only once no lower order can still be
    # chosen: a lower order within `improvement` of every higher order seen so far stays a
    # candidate until all higher orders are seen
    from ident.identify.fit import _order_settled
    assert _order_settled([(2, 0.5), (3, 0.0009)], 1e-3, 0.1)
    assert not _order_settled([(2, 0.00105), (3, 0.001)], 1e-3, 0.1)  # 2 still in
    assert _order_settled([(2, 0.00105), (3, 0.001), (4, 0.0005)], 1e-3, 0.1)
    assert not _order_settled([(2, 0.5), (3, float("nan"))], 1e-3, 0.1)
    assert not _order_settled([(2, 0.5), (3, 0.01)], 1e-3, 0.1)  # floor not reached


def test_select_order_skips_orders_the_data_cannot_identify():
    truth = TRUTHS["order2"]
    f = np.array([1.0, 2.0, 3.0, 5.0])  # 8 real equations: at most 4 poles (+ 4 numerator)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FitWarning)
        fit, table = select_order(f, truth.response(f), orders=range(1, 7), relative_num=-1,
                                  stop_early=False)
    assert [n for n, e in table if np.isnan(e)] == [5, 6]
    assert fit.n_den == 2


def test_select_order_warns_when_the_highest_order_is_needed():
    truth = TRUTHS["order6-zero"]
    with pytest.warns(FitWarning, match="highest order"):
        fit, _ = select_order(F_HZ, truth.response(F_HZ), orders=[2, 3, 4], relative_num=-1)
    assert fit.n_den == 4


# ----------------------------------------------------------------------------------------------
# vector fitting and modal forms
# ----------------------------------------------------------------------------------------------


@pytest.fixture
def mimo(rng):
    """A 3x2 response with 8 common poles and outputs of very different units."""
    poles = _with_conj([_pair(1.2, 0.3), _pair(3.5, 0.05), _pair(9.0, 0.15), _pair(15.0, 0.04)])
    p_out, m_in = 3, 2
    gains = np.array([1e-5, 1.0, 1e5])[:, None]  # velocity/N, -, N/m
    res = np.zeros((poles.size, p_out, m_in), dtype=complex)
    for k in range(0, poles.size, 2):
        r = (rng.standard_normal((p_out, m_in)) + 1j * rng.standard_normal((p_out, m_in)))
        res[k] = r * np.abs(poles[k]) * gains
        res[k + 1] = np.conj(res[k])
    direct = rng.standard_normal((p_out, m_in)) * gains
    s = 2j * np.pi * F_HZ
    H = np.einsum("kpm,kf->pmf", res, 1 / (s[None] - poles[:, None])) + direct[:, :, None]
    return poles, res, direct, H


def test_vector_fitting_recovers_common_poles(mimo):
    poles, res, direct, H = mimo
    vf = fit_common_poles(F_HZ, H, n_poles=8)
    assert isinstance(vf, VfFit) and vf.residues.shape == (8, 3, 2)
    assert vf.fit_error.shape == (3, 2) and np.all(vf.fit_error < FIT_ERROR_EXACT)
    p_fit, r_fit = _sorted(vf.poles, vf.residues)
    p_true, r_true = _sorted(poles, res)
    assert_allclose(p_fit, p_true, rtol=RTOL_EXACT)
    assert_allclose(r_fit, r_true, rtol=RTOL_EXACT)
    assert_allclose(vf.direct, direct, rtol=RTOL_EXACT)
    _assert_close_per_pair(vf.evaluate(F_HZ), H, RTOL_EXACT)


def test_vector_fitting_with_noise_and_pair_weights(mimo, rng):
    _, _, _, H = mimo
    Hn = H * (1 + NOISE * (rng.standard_normal(H.shape) + 1j * rng.standard_normal(H.shape))
              / np.sqrt(2))
    vf = fit_common_poles(F_HZ, Hn, n_poles=8, weight=1 / np.abs(Hn) ** 2)
    assert np.all(np.abs(vf.fit_error - NOISE) < 0.2 * NOISE)
    assert np.max(np.abs(20 * np.log10(np.abs(vf.evaluate(F_HZ) / H)))) < DB_NOISY
    assert np.all(vf.poles.real < 0)


def test_modal_forms_reproduce_evaluate(mimo):
    poles, res, direct, H = mimo
    f_out = np.linspace(0.1, 40.0, 300)
    vf = fit_common_poles(F_HZ, H, n_poles=8)
    md = vf.to_modal()
    assert md.lam.size == 4 * 2 and md.B.shape == (8, 2) and md.C.shape == (3, 8)
    H_vf = vf.evaluate(f_out)
    _assert_close_per_pair(md.frequency_response(f_out), H_vf, RTOL_MODAL)
    # per-pair fits, one pair missing (zero); one real pole in pair (0, 1)
    fits = {(o, i): fit_tf(F_HZ, H[o, i], n_den=8, n_num=8)
            for o in range(3) for i in range(2) if (o, i) != (1, 1)}
    fits[(0, 1)] = fit_tf(F_HZ, H[0, 1], n_den=9, n_num=9)
    assert np.sum(fits[(0, 1)].poles.imag == 0) >= 1
    md2 = tf_fits_to_modal(fits, 3, 2)
    assert md2.lam.size == 4 * 4 + 5
    Hm = md2.frequency_response(f_out)
    for (o, i), fit in fits.items():
        h = fit.evaluate(f_out)
        assert_allclose(Hm[o, i], h, rtol=0, atol=RTOL_MODAL * np.abs(h).max())
    assert np.all(Hm[1, 1] == 0)


# ----------------------------------------------------------------------------------------------
# bad inputs, documentation
# ----------------------------------------------------------------------------------------------

_H = TRUTHS["order2"].response(F_HZ)


@pytest.mark.parametrize("kwargs, exc, match", [
    (dict(n_den=2, n_num=3), ValueError, "improper"),
    (dict(n_den=0, n_num=0), ValueError, "n_den"),
    (dict(n_den=2, n_num=1, h=_H[:-1]), ValueError, "one value per frequency"),
    (dict(n_den=2, n_num=1, weight=-np.ones(F_HZ.size)), ValueError, ">= 0"),
    (dict(n_den=2, n_num=1, weight=np.ones(3)), ValueError, "weight has shape"),
    (dict(n_den=2, n_num=1, h=np.where(F_HZ > 10, np.nan, _H)), ValueError,
     "not finite at 410 weighted"),
    (dict(n_den=2, n_num=1, method="newton"), ValueError, "method must be"),
    (dict(n_den=2, n_num=1, h=np.zeros(F_HZ.size)), IdentificationError, "nothing to fit"),
    (dict(n_den=8, n_num=8, weight=(np.arange(F_HZ.size) < 8).astype(float)), IdentificationError,
     "fewer real equations"),
    (dict(n_den=2, n_num=1, f_hz=-F_HZ), ValueError, ">= 0 Hz"),
])
def test_fit_tf_rejects_bad_input(kwargs, exc, match):
    args = {"f_hz": F_HZ, "h": _H}
    args.update(kwargs)
    with pytest.raises(exc, match=match):
        fit_tf(args.pop("f_hz"), args.pop("h"), **args)


def test_other_functions_reject_bad_input(mimo):
    H = mimo[3]
    with pytest.raises(ValueError, match="expected \\(n_out, n_in, 800\\)"):
        fit_common_poles(F_HZ, H[0], n_poles=4)
    with pytest.raises(IdentificationError, match="fewer poles"):
        fit_common_poles(F_HZ[:4], H[:, :, :4], n_poles=8)
    with pytest.raises(ValueError, match="relative_num"):
        select_order(F_HZ, _H, relative_num=1)
    fit = fit_tf(F_HZ, _H, n_den=2, n_num=1)
    with pytest.raises(ValueError, match="index pair"):
        tf_fits_to_modal({(2, 0): fit}, 2, 1)
    with pytest.raises(TypeError, match="must be a TfFit"):
        tf_fits_to_modal({(0, 0): "fit"}, 1, 1)


def test_results_are_frozen():
    fit = fit_tf(F_HZ, _H, n_den=2, n_num=1)
    assert isinstance(fit, TfFit)
    with pytest.raises(AttributeError):
        fit.fit_error = 0.0


def test_docstring_examples_run():
    result = doctest.testmod(fitmod, optionflags=doctest.ELLIPSIS)
    assert result.failed == 0 and result.attempted > 0

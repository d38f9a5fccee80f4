"""Tests of ident.identify.crossval: time blocks of a session, the blocks' deviations (known
answer), the measured-over-stated ratio on blocks of known error, and the round trip of the
cross-validation through a model file."""

from dataclasses import replace

import numpy as np
import pytest
from numpy.testing import assert_allclose

from ident.identify.crossval import (
    CV_BLOCKS,
    block_deviations,
    cross_validation_ratio,
    split_session,
)
from ident.identify.frf import Frf

# Sums and products of a few exact numbers: round-off only.
RTOL_EXACT = 1e-6  # complex64 storage of the deviations
#: 400 lines x 6 pairs of blocks whose errors are Gaussian of a known standard error: the
#: pooled ratio (2,400 lines, 2 real degrees of freedom each, one per block pair) is within
#: 5 % of 1 (its standard deviation is about 1.5 %).
RTOL_RATIO = 0.05


def _frf(H, sigma, f):
    n_out, n_in, _ = H.shape
    return Frf(f_hz=f, H=H, input_names=tuple(f"u{i}" for i in range(n_in)),
               output_names=tuple(f"y{o}" for o in range(n_out)),
               multiple_coherence=np.ones((n_out, f.size)),
               partial_coherence=np.ones(H.shape), input_condition=np.ones(f.size),
               independent_fraction=np.ones((n_in, f.size)),
               flagged=np.zeros((n_in, f.size), bool), n_averages=10,
               cbar_n_s_m=np.full(4, 1000.0), fs_hz=100.0, sigma=sigma,
               replaced=np.zeros(H.shape, bool))


def test_split_session_halves_every_run(linear_session):
    """Two blocks: each run cut in two contiguous halves, the same names and setups."""
    a, b = split_session(linear_session, 2)
    for full, ra, rb in zip(linear_session.runs, a.runs, b.runs):
        n = full.n_samples // 2
        assert ra.name == rb.name == full.name and ra.setup == full.setup
        assert ra.n_samples == rb.n_samples == n
        key = next(iter(full.channels))
        assert_allclose(np.concatenate([ra.channels[key], rb.channels[key]]),
                        full.channels[key][:2 * n])
    with pytest.raises(ValueError, match="at least 2"):
        split_session(linear_session, 1)


def test_block_deviations_known_answer():
    """Two blocks H(1 +- d): each block's deviation is +-d (sqrt(K - 1) = 1), at any
    frequency of the grid (a constant deviation interpolates to itself)."""
    f = np.linspace(0.0, 10.0, 11)
    H = np.full((1, 2, f.size), 2.0 + 1.0j)
    d = np.array([0.01, -0.02j])[None, :, None]
    blocks = np.stack([H * (1 + d), H * (1 - d)])
    frf = _frf(H, np.full(H.shape, 0.01), f)
    dev = block_deviations(frf, blocks, [0.5, 3.25, 9.0])
    assert dev.shape == (2, 1, 2, 3) and dev.dtype == np.complex64
    assert_allclose(dev[0], np.broadcast_to(d, (1, 2, 3)), rtol=RTOL_EXACT)
    assert_allclose(dev[1], -np.broadcast_to(d, (1, 2, 3)), rtol=RTOL_EXACT)


def test_ratio_is_one_for_blocks_of_the_stated_error(rng):
    """Blocks whose errors are Gaussian with K times the full estimate's stated variance (each
    block has 1/K of the data): the measured over stated ratio is 1, per band and overall;
    doubling the blocks' errors doubles it."""
    K, f = CV_BLOCKS, np.linspace(0.5, 20.0, 400)
    H = np.ones((2, 3, f.size), complex) * (1 + 0.5j)
    sigma = np.full(H.shape, 0.01)
    frf = _frf(H, sigma, f)
    noise = (rng.standard_normal((K,) + H.shape)
             + 1j * rng.standard_normal((K,) + H.shape)) / np.sqrt(2)
    for factor in (1.0, 2.0):
        blocks = H + factor * np.sqrt(K) * sigma * noise
        doc = cross_validation_ratio(frf, blocks)
        assert doc["blocks"] == K
        assert_allclose(doc["ratio_all"], factor, rtol=RTOL_RATIO)
        assert_allclose(doc["ratio_band"], factor, rtol=3 * RTOL_RATIO)
        assert np.asarray(doc["ratio"]).shape == (2, 3, len(doc["band_edges_hz"]) - 1)


def test_ratio_needs_a_conditioned_frf():
    f = np.linspace(0.5, 20.0, 50)
    frf = replace(_frf(np.ones((1, 1, 50), complex), None, f))
    with pytest.raises(ValueError, match="condition_frf"):
        cross_validation_ratio(frf, np.ones((2, 1, 1, 50), complex))


def test_identified_model_keeps_its_cross_validation(four_post_model, tmp_path):
    """Identification keeps the deviations and their grid with the FRF; the model file
    round-trips them; an older file (without them) loads with none."""
    from ident.identify.model import load_model

    frf = four_post_model.frf
    cv = frf.settings["cross_validation"]
    assert frf.cv_deviation.shape == (cv["blocks"],) + frf.H.shape[:2] + (len(cv["f_hz"]),)
    assert np.all(np.isfinite(frf.cv_deviation)) and np.any(frf.cv_deviation != 0)
    path = tmp_path / "m.npz"
    four_post_model.save(path)
    back = load_model(path).frf
    assert_allclose(back.cv_deviation, frf.cv_deviation)
    assert back.settings["cross_validation"]["f_hz"] == cv["f_hz"]
    old = replace(four_post_model, frf=replace(frf, cv_deviation=None))
    old.save(tmp_path / "old.npz")
    assert load_model(tmp_path / "old.npz").frf.cv_deviation is None

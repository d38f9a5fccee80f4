"""Tests of ident.identify.coverage: what a session covered, and predictions beyond it."""

import numpy as np
import pandas as pd
import pytest

from ident.data.channels import CORNERS
from ident.identify.coverage import (
    COVERAGE_RMS_MARGIN,
    Coverage,
    outside_coverage,
    session_coverage,
)


def test_session_coverage_known_answer(paper_session):
    cov = session_coverage(paper_session)
    want = np.zeros(4)
    for run in paper_session.runs:
        for k, c in enumerate(CORNERS):
            x = run.channels[f"shock_travel_{c}"]
            want[k] = max(want[k], np.std(x))
    np.testing.assert_allclose(cov.travel_rms_m, want, rtol=1e-12)
    assert cov.contact_min_n is None and cov.runs == len(paper_session.runs)
    back = Coverage.from_dict(cov.to_dict())
    np.testing.assert_array_equal(back.velocity_rms_m_s, cov.velocity_rms_m_s)


def test_outside_coverage_flags_travel_velocity_and_contact():
    cov = Coverage(travel_rms_m=np.full(4, 0.004), velocity_rms_m_s=np.full(4, 0.05),
                   travel_max_m=np.full(4, 0.015), contact_min_n=np.full(4, 800.0), runs=3)
    inside = 1.0 + 0.5 * COVERAGE_RMS_MARGIN
    outside = 1.0 + 2.0 * COVERAGE_RMS_MARGIN
    t = pd.DataFrame({**{f"shock_travel_rms_{c}": [0.004 * inside, 0.004 * outside]
                         for c in CORNERS},
                      **{f"shock_velocity_rms_{c}": [0.05, 0.05] for c in CORNERS},
                      "tire_contact_min_LR": [900.0, 100.0]}, index=["ok", "far"])
    got = outside_coverage(t, cov, static_corner_load_n=np.full(4, 3000.0))
    assert {(s, c, w) for s, c, w, _, _ in got} == (
        {("far", c, "travel") for c in CORNERS} | {("far", "LR", "contact")})


@pytest.mark.parametrize("margin", [0.0, 0.5])
def test_margin_is_used(margin):
    cov = Coverage(np.ones(4), np.ones(4), np.ones(4), None, 1)
    t = pd.DataFrame({"shock_travel_rms_LF": [1.2]}, index=["a"])
    assert bool(outside_coverage(t, cov, rms_margin=margin)) == (margin < 0.2)

"""Eq. 10 (η, φ) and eq. 9 (M = the OVP closest to the centre)."""

import math

import numpy as np
import pytest

from companion.vision.heading import closest_to_centre, heading_from_vp

# Paper Table IV rows 2-8: (M_x, η). Row 1 is a typo in the paper (74.44° with D = 240).
TABLE_IV = [
    (768.64, 72.65),
    (693.24, 70.90),
    (516.5, 65.07),
    (279.43, 49.34),
    (257.28, 46.99),
    (233.17, 44.17),
    (164.82, 34.48),
]
CENTRE = np.array([319.5, 239.5])


@pytest.mark.parametrize(("m_x", "eta"), TABLE_IV)
def test_eq10_reproduces_table_iv(m_x, eta):
    vp = np.array([CENTRE[0] + m_x, CENTRE[1], 1.0])
    h = heading_from_vp(vp, CENTRE, depth_px=240.0)
    assert h.eta_deg == pytest.approx(eta, abs=0.01)
    assert h.phi_deg == pytest.approx(0.0, abs=1e-9)
    assert h.m_px == pytest.approx((m_x, 0.0))


def test_table_iv_row_1_is_74_44_not_76_43():
    vp = np.array([CENTRE[0] + 861.77, CENTRE[1], 1.0])
    assert heading_from_vp(vp, CENTRE, 240.0).eta_deg == pytest.approx(74.44, abs=0.01)


def test_sign_left_is_negative_and_homogeneous_scale_does_not_matter():
    vp = np.array([CENTRE[0] - 100.0, CENTRE[1], 1.0])
    a = heading_from_vp(vp, CENTRE, 240.0)
    b = heading_from_vp(-3.7 * vp, CENTRE, 240.0)
    assert a.eta_deg == pytest.approx(-math.degrees(math.atan(100 / 240)))
    assert b.eta_deg == pytest.approx(a.eta_deg)


def test_phi_positive_when_m_is_above_centre():
    vp = np.array([CENTRE[0] + 240.0, CENTRE[1] - 100.0, 1.0])
    h = heading_from_vp(vp, CENTRE, 240.0)
    assert h.phi_deg == pytest.approx(math.degrees(math.atan(100 / math.hypot(240, 240))))


def test_vp_at_infinity_gives_plus_minus_90_without_division():
    h = heading_from_vp(np.array([1.0, 0.0, 0.0]), CENTRE, 240.0)
    assert h.eta_deg == pytest.approx(90.0)
    assert h.m_px is None


def test_closest_to_centre_prefers_finite_and_near():
    vps = np.array(
        [[1.0, 0.0, 0.0], [CENTRE[0] + 50, CENTRE[1], 1.0], [CENTRE[0] - 40, CENTRE[1], 1.0]]
    )
    assert closest_to_centre(vps, CENTRE) == 2
    assert closest_to_centre(vps[:2], CENTRE) == 1

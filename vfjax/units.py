"""Unit conversions. vfjax works in CGS inside (cm, g, s, dyne, dyne/cm², poise).

The seed paper reports stiffness in N/m and the area scale in pixels per mm²; these helpers
convert at the boundary so that every public constructor can take the paper's units.
"""

#: 1 N/m expressed in dyne/cm.
DYNE_PER_CM_PER_N_PER_M = 1000.0
#: 1 mm² expressed in cm².
CM2_PER_MM2 = 0.01
#: 1 Pa expressed in dyne/cm².
DYNE_PER_CM2_PER_PA = 10.0


def n_per_m_to_dyne_per_cm(k_n_per_m):
    """Stiffness: N/m -> dyne/cm."""
    return k_n_per_m * DYNE_PER_CM_PER_N_PER_M


def dyne_per_cm_to_n_per_m(k_dyne_per_cm):
    """Stiffness: dyne/cm -> N/m."""
    return k_dyne_per_cm / DYNE_PER_CM_PER_N_PER_M


def cm2_to_px(area_cm2, s_px_per_mm2):
    """Area: cm² -> pixels, with the scaling factor S in pixels per mm²."""
    return area_cm2 / CM2_PER_MM2 * s_px_per_mm2


def px_to_cm2(area_px, s_px_per_mm2):
    """Area: pixels -> cm², with the scaling factor S in pixels per mm²."""
    return area_px / s_px_per_mm2 * CM2_PER_MM2

"""Physical constants and the unit conversions used at the edges.

Inside the models everything is SI, except mass, which is in tonnes [t] because the
sources' specific forces are per unit weight in kN: P [t] * g [m/s^2] = weight [kN],
and a force [N] divided by that weight is a specific force in [N/kN].
"""

G = 9.81
"""Gravity [m/s^2] (the value the sources use, docs/model.md, Units)."""

KMH = 1.0 / 3.6
"""One km/h in [m/s]."""


def kmh_to_mps(v_kmh):
    """Speed [km/h] -> [m/s]."""
    return v_kmh * KMH


def mps_to_kmh(v_mps):
    """Speed [m/s] -> [km/h]."""
    return v_mps * 3.6


def resistance_kmh_to_si(a, b, c):
    """Resistance coefficients for V in km/h -> for V in m/s.

    ``w0 = a + b V + c V^2`` [N/kN] with V [km/h] becomes ``A0 + A1 V + A2 V^2`` with V [m/s]:
    A0 = a [N/kN], A1 = 3.6 b [N/kN/(m/s)], A2 = 3.6^2 c [N/kN/(m/s)^2].
    """
    return a, 3.6 * b, 3.6 * 3.6 * c

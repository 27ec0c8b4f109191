"""A scalar, numba-compiled loop of the same model at a fixed step: the paper's practice.

Used only as a benchmark baseline (throughput) and as a second, independently written
integrator (accuracy). Regime switches are per-stage masks, as a straightforward
implementation would write them; the closure hold starts at the first step whose velocity is
no longer negative while the folds are in contact and lasts round(t_c / dt) steps.
"""

import math

import numba
import numpy as np


@numba.njit(cache=True, fastmath=False)
def _acc(x, v, closing, K, Cf, M, l, d, Ag0, Ps, rho, mu, x0, xc, fs_on):
    area = Ag0 + 2.0 * l * x
    fa = 0.0
    if x > x0:
        c = 12.0 * mu * d * l * l
        a2 = area * area
        u = 2.0 * Ps * a2 / (c + math.sqrt(c * c + 1.75 * rho * Ps * a2 * a2))
        pg = 0.5 * rho * u * u
        fa = 0.5 * (Ps - 1.87 * pg) * l * d
    ffs = 0.0
    if fs_on and x > x0 and x <= xc and closing:
        ffs = -fa * (x - xc) / (x0 - xc)
    damp = Cf * math.tanh(xc - x) if x < xc else 0.0
    return (-K * x - damp * v + fa + ffs) / M


@numba.njit(cache=True, fastmath=False)
def simulate_gaw(K, Cf, S, t_c, Ps, M, l, fps, n_frames, substeps, fs_on=True, hold_on=True):
    """GAW (px) of the paper's model with stiffness K (dyne/cm), C_f (g/s), S (px/mm²),
    t_c (s), P_s (dyne/cm²), mass M (g) and length l (cm), starting at rest at x_0."""
    d, Ag0, rho, mu = 0.32, 0.05, 1.3e-3, 1.8e-4
    x0 = -Ag0 / (2.0 * l)
    c = 12.0 * mu * d * l * l
    u_c = math.sqrt(2.0 * Ps / 1.87 / rho)
    xc = (math.sqrt(c * u_c / (Ps - 0.4375 * rho * u_c * u_c)) - Ag0) / (2.0 * l)
    dt = 1.0 / (fps * substeps)
    hold_steps = int(round(t_c / dt))
    out = np.empty(n_frames)
    x, v = x0, 0.0
    hold = 0
    out[0] = S * 100.0 * (Ag0 + 2.0 * l * x)
    for i in range(1, (n_frames - 1) * substeps + 1):
        if hold > 0:
            hold -= 1
        else:
            closing = v < 0.0
            a1 = _acc(x, v, closing, K, Cf, M, l, d, Ag0, Ps, rho, mu, x0, xc, fs_on)
            x2, v2 = x + 0.5 * dt * v, v + 0.5 * dt * a1
            a2 = _acc(x2, v2, v2 < 0.0, K, Cf, M, l, d, Ag0, Ps, rho, mu, x0, xc, fs_on)
            x3, v3 = x + 0.5 * dt * v2, v + 0.5 * dt * a2
            a3 = _acc(x3, v3, v3 < 0.0, K, Cf, M, l, d, Ag0, Ps, rho, mu, x0, xc, fs_on)
            x4, v4 = x + dt * v3, v + dt * a3
            a4 = _acc(x4, v4, v4 < 0.0, K, Cf, M, l, d, Ag0, Ps, rho, mu, x0, xc, fs_on)
            xn = x + dt / 6.0 * (v + 2.0 * v2 + 2.0 * v3 + v4)
            vn = v + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
            if hold_on and xn <= x0 and v < 0.0 and vn >= 0.0:
                vn = 0.0
                hold = hold_steps
            x, v = xn, vn
        if i % substeps == 0:
            out[i // substeps] = S * 100.0 * (Ag0 + 2.0 * l * x)
    return out


def simulate_preset(name: str, fps: float = 4000.0, n_frames: int = 201, substeps: int = 128):
    """`simulate_gaw` with the parameters of the vfjax preset ``name``."""
    import vfjax

    p = {k: float(v) for k, v in vfjax.preset(name).params().items()}
    return simulate_gaw(
        p["K"], p["C_f"], p["S"], p["t_c"], p["P_s"], p["M"], p["l"], fps, n_frames, substeps
    )

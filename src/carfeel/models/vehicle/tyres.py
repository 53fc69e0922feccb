"""Brush tyre: lateral force and pneumatic aligning moment with a friction coefficient.

Parabolic contact pressure, one stiffness per tyre (Pacejka, Tyre and Vehicle Dynamics, 2nd ed.,
sec. 3.2.2). With x = C*|alpha| / (3*mu*Fz), the share of the contact length that slides:

    Fy = mu*Fz * (1 - (1 - x)^3) * sign(alpha)      x < 1;  mu*Fz * sign(alpha) beyond
    Mz = t0 * C * alpha * (1 - x)^3                 x < 1;  0 beyond (pneumatic moment)

so Fy = C*alpha and Mz = t0*Fy at small slip, the pneumatic trail Mz/Fy falls from t0 at zero
slip to 0 at full sliding, and Mz peaks at x = 1/4 while Fy is still rising (it saturates at
x = 1). Small angles: alpha stands for tan(alpha). Signs: alpha positive gives a positive
(leftward) force; Mz has the sign of Fy and is the magnitude that turns the wheel back (the force
acts t0 behind the contact centre).

The friction coefficient falls with load, mu_i = mu * (1 - e * (Fz_i / Fz0 - 1)) (Pacejka's
pDy2): two tyres of an axle with load transfer grip less than the same tyres evenly loaded, which
is how roll stiffness distribution sets the balance at the limit.
"""

from __future__ import annotations


def brush(
    slip_rad: float, load_N: float, stiffness_N_rad: float, mu: float, trail_m: float
) -> tuple[float, float, float]:
    """(Fy in N, Mz in Nm, share of the grip used 0..1) of one tyre at a slip angle and load."""
    grip = mu * load_N
    if grip <= 0.0:
        return 0.0, 0.0, 1.0
    x = stiffness_N_rad * abs(slip_rad) / (3.0 * grip)
    sign = 1.0 if slip_rad >= 0.0 else -1.0
    if x >= 1.0:
        return sign * grip, 0.0, 1.0
    rest = 1.0 - x
    rest3 = rest * rest * rest
    used = 1.0 - rest3
    return sign * grip * used, trail_m * stiffness_N_rad * slip_rad * rest3, used


def load_sensitive_mu(mu: float, load_N: float, nominal_load_N: float, sensitivity: float) -> float:
    """mu * (1 - e * (Fz / Fz0 - 1)), never below a tenth of mu."""
    return max(0.1 * mu, mu * (1.0 - sensitivity * (load_N / nominal_load_N - 1.0)))

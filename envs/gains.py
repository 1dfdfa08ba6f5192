"""Gain design of the joint PD controller (:data:`envs.spec.DEFAULT_KP` came from it), and when
gains are stable.

The gains are designed per joint, each taken alone at a bound of its diagonal inertia over the
joint space (:func:`joint_inertia_bounds`). Importing this module is cheap: Pinocchio loads only
when an inertia bound is first needed.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

INERTIA_SAMPLES = 4096
"""Configurations sampled (uniform in [-pi, pi]^6) to bound the diagonal of the mass matrix."""

INERTIA_SEED = 5
"""Seed of that sample, fixed so the bounds (and the checks on them) are reproducible."""


@functools.cache
def joint_inertia_bounds() -> tuple[np.ndarray, np.ndarray]:
    """Smallest and largest diagonal entry of the UR5's mass matrix, per joint.

    Returns
    -------
    low, high : (6,) float, kg m^2
        Min and max of ``M_ii(q)`` over :data:`INERTIA_SAMPLES` configurations uniform in
        [-pi, pi]^6: an estimate from a sample, within 0.4 % of the extremes of a ten times
        larger one.
    """
    import pinocchio as pin  # here, so that reading a task loads no physics

    import ur5kin

    model = ur5kin.load_model()
    data = model.createData()
    q = np.random.default_rng(INERTIA_SEED).uniform(-np.pi, np.pi, (INERTIA_SAMPLES, 6))
    diag = np.array([np.diag(pin.crba(model, data, qi)) for qi in q])
    return diag.min(axis=0), diag.max(axis=0)


def pd_stability_violations(kp: Any, kd: Any, h: float) -> list[str]:
    """Joints whose PD loop is unstable under semi-implicit Euler with step ``h``.

    For one joint of inertia I, the substep maps ``(q, h v)`` by the matrix
    ``[[1 - a, 1 - b], [-a, 1 - b]]`` with ``a = kp h^2 / I``, ``b = kd h / I``; it is stable
    (Jury's test) iff ``0 < b < 2`` and ``a + 2 b < 4``. This checks that at each joint's
    smallest diagonal inertia (:func:`joint_inertia_bounds`), where the loop is fastest. It is a
    necessary condition; the coupled loop is tested on sampled configurations in the test suite.

    Parameters
    ----------
    kp : (6,) float, N m/rad
    kd : (6,) float, N m s/rad
    h : float, s

    Returns
    -------
    problems : list of str
        One message per unstable joint (empty when all pass).
    """
    low, _ = joint_inertia_bounds()
    a = np.asarray(kp, dtype=float) * h**2 / low
    b = np.asarray(kd, dtype=float) * h / low
    return [
        f"joint {j + 1}: kd h / I = {b[j]:.3g} (need < 2), kp h^2 / I + 2 kd h / I = "
        f"{a[j] + 2 * b[j]:.3g} (need < 4) at I = {low[j]:.4g} kg m^2"
        for j in range(6) if not (0.0 < b[j] < 2.0 and a[j] + 2.0 * b[j] < 4.0)
    ]


CONTACT_MIN_EFFECTIVE_MASS = 2.4
"""Smallest effective mass (kg) of a link's deepest point along a world axis,
``1 / (e^T J M^-1 J^T e)``: 3.0 kg along z and 2.5 kg along x or y (wrist_3_link) over 2000
configurations uniform in [-pi, pi]^6, rounded down; tested on a fresh sample. The stiffest,
fastest contact mode the compliant model can excite; :func:`contact_stability_violations`."""


def contact_stability_violations(stiffness: float, damping: float, h: float) -> list[str]:
    """Why a compliant contact ``(k, c)`` would be unstable under semi-implicit Euler with step h.

    One contact on a point of effective mass m is the loop of :func:`pd_stability_violations`
    with ``a = k h^2 / m`` and ``b = c h / m`` (the friction's viscous slope is c too); stable iff
    ``b < 2`` and ``a + 2 b < 4``. Checked at :data:`CONTACT_MIN_EFFECTIVE_MASS`, where the loop
    is fastest. Necessary, not sufficient: the coupled loop with the PD is tested on sampled
    contact configurations in the test suite.

    Parameters
    ----------
    stiffness : float, N/m
    damping : float, N s/m
    h : float, s

    Returns
    -------
    problems : list of str
        Empty when stable.
    """
    m = CONTACT_MIN_EFFECTIVE_MASS
    a, b = stiffness * h * h / m, damping * h / m
    if b < 2.0 and a + 2.0 * b < 4.0:
        return []
    return [f"at the smallest effective mass {m} kg, c h / m = {b:.3g} (need < 2) and "
            f"k h^2 / m + 2 c h / m = {a + 2.0 * b:.3g} (need < 4) for k = {stiffness} N/m, "
            f"c = {damping} N s/m, h = {h} s"]

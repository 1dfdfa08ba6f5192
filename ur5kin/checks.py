"""Input checks of the public ur5kin functions: each error names the value and the expectation."""

from __future__ import annotations

from typing import Any

import numpy as np

MOVING_JOINTS_RANGE = (1, 6)
"""Fewest and most moving joints of a sub-chain (joints 1..n move; the task itself uses 2..6,
:data:`envs.spec.N_JOINTS_RANGE`)."""

ROTATION_TOL = 1e-6
"""Largest deviation of ``R^T R`` from the identity, and of ``det R`` from 1, accepted in a pose."""


def _describe(x: Any) -> str:
    text = np.array2string(np.asarray(x), threshold=12, precision=6)
    return text if len(text) < 200 else text[:200] + "..."


def real_array(x: Any, name: str, what: str) -> np.ndarray:
    """Return ``x`` as a float64 array, or raise ``ValueError`` naming ``name`` and ``what``.

    Complex input is refused rather than cast (numpy's cast drops the imaginary part with only
    a warning); so are strings, None and other objects that are not real numbers. Booleans and
    integers are taken as numbers.
    """
    arr = np.asarray(x)
    if arr.dtype.kind not in "biuf":
        if arr.dtype.kind == "c":
            raise ValueError(f"{name} must be real ({what}); got complex values {_describe(x)}")
        try:
            arr = np.asarray(x, dtype=float)
        except (TypeError, ValueError) as err:
            raise ValueError(f"{name} must be an array of real numbers ({what}); got {x!r}"
                             ) from err
    return arr.astype(float, copy=False)


def joint_array(q: Any, name: str = "q", n: int = 6, what: str = "joint angles in rad"
                ) -> np.ndarray:
    """Return ``q`` as a finite, real float64 array of shape ``(..., n)``, or raise ``ValueError``.

    Parameters
    ----------
    q : array_like, (..., n) float, rad
    name : str
        Name used in the error message.
    n : int
        Expected trailing dimension.
    what : str
        What the values are, with their unit, for the error message.
    """
    arr = real_array(q, name, what)
    if arr.ndim == 0 or arr.shape[-1] != n:
        describe = f"{what}, joints 1-{n}" if what == "joint angles in rad" else what
        raise ValueError(f"{name} must have shape (..., {n}) ({describe}); got shape {arr.shape}")
    check_finite(arr, name)
    return arr


def joint_count(n: Any, name: str = "n_joints") -> int:
    """Return ``n`` as an int in :data:`MOVING_JOINTS_RANGE`, or raise ``ValueError``."""
    lo, hi = MOVING_JOINTS_RANGE
    if isinstance(n, bool | np.bool_) or not isinstance(n, int | np.integer) or not lo <= n <= hi:
        raise ValueError(f"{name} must be an integer in {lo}..{hi} (joints 1..n move); got {n!r}")
    return int(n)


def check_finite(arr: np.ndarray, name: str) -> None:
    """Raise ``ValueError`` naming the first non-finite entry of ``arr``."""
    finite = np.isfinite(arr)
    if not finite.all():
        where = tuple(int(i) for i in np.argwhere(~finite)[0])
        raise ValueError(
            f"{name} must be finite; {name}[{', '.join(map(str, where))}] = {arr[where]}"
        )


def pose_array(pose: Any, name: str = "pose") -> np.ndarray:
    """Return ``pose`` as a float64 ``(..., 4, 4)`` rigid transform, or raise ``ValueError``.

    A rigid transform has an orthonormal rotation block with determinant +1 (to
    :data:`ROTATION_TOL`) and a last row of ``[0, 0, 0, 1]``.
    """
    arr = real_array(pose, name, "a 4 x 4 homogeneous transform, translation in m")
    if arr.ndim < 2 or arr.shape[-2:] != (4, 4):
        raise ValueError(f"{name} must have shape (..., 4, 4); got shape {arr.shape}")
    check_finite(arr, name)
    rot = arr[..., :3, :3]
    ortho = np.abs(np.swapaxes(rot, -1, -2) @ rot - np.eye(3)).max(axis=(-2, -1))
    det = np.linalg.det(rot)
    bottom = np.abs(arr[..., 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=-1)
    bad = (ortho > ROTATION_TOL) | (np.abs(det - 1.0) > ROTATION_TOL) | (bottom > 0.0)
    if np.any(bad):
        idx = tuple(int(i) for i in np.argwhere(np.atleast_1d(bad))[0]) if bad.ndim else ()
        one = arr[idx] if idx else arr
        raise ValueError(
            f"{name} must be a rigid transform (orthonormal rotation with det +1 within "
            f"{ROTATION_TOL}, last row [0, 0, 0, 1]); got {_describe(one)}"
        )
    return arr

"""Public forward kinematics: ``fk``, ``fk_pose``, ``link_poses`` and ``jacobian``.

Each function takes ``q (..., 6)`` in rad and answers in the ``base_link`` frame. A single
configuration ``(6,)`` goes through Pinocchio (fastest for one call); a batch goes through the
closed form of :mod:`ur5kin.closed_form`; a torch tensor stays a tensor (any device, float32 or
float64) and goes through the same closed form in torch.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
import pinocchio as pin

from ur5kin import closed_form
from ur5kin.checks import check_finite, joint_array
from ur5kin.model import TOOL_FRAME, load_model
from ur5kin.world import to_world

_local = threading.local()


def _pinocchio() -> tuple[pin.Model, pin.Data, int]:
    """The shared model with a ``Data`` of this thread's own (Pinocchio's model/data split)."""
    cached = getattr(_local, "pin", None)
    if cached is None:
        model = load_model()
        cached = (model, model.createData(), model.getFrameId(TOOL_FRAME))
        _local.pin = cached
    return cached


def _check_tensor(q: Any) -> Any:
    if q.ndim == 0 or q.shape[-1] != 6:
        raise ValueError(
            f"q must have shape (..., 6) (joint angles in rad, joints 1-6); got shape "
            f"{tuple(q.shape)}"
        )
    if not q.is_floating_point():  # complex tensors are not floating point: refused too
        raise ValueError(f"q must be a float32 or float64 tensor; got dtype {q.dtype}")
    import torch

    if not bool(torch.isfinite(q).all()):
        check_finite(q.detach().cpu().numpy(), "q")
    return q


def _dispatch(q: Any, batched: Any, tail: tuple[int, ...], single: Any = None) -> Any:
    """Route ``q``: a tensor or a numpy batch to the closed form ``batched`` (in cache-sized
    blocks), one numpy configuration to Pinocchio's ``single(model, data, frame, q)`` if given."""
    if closed_form.torch_if_tensor(q) is not None:
        return closed_form.chunked(batched, _check_tensor(q), tail)
    q = joint_array(q)
    if q.ndim == 1 and single is not None:
        return single(*_pinocchio(), q)
    return closed_form.chunked(batched, q, tail)


def _single_placement(part: str) -> Any:
    """``single(model, data, frame, q)``: Pinocchio's ``part`` (``translation``, ``homogeneous``)
    of the frame's placement at ``q``."""
    def single(model: pin.Model, data: pin.Data, frame: int, q: np.ndarray) -> np.ndarray:
        pin.forwardKinematics(model, data, q)
        return getattr(pin.updateFramePlacement(model, data, frame), part).copy()
    return single


_single_position, _single_pose = _single_placement("translation"), _single_placement("homogeneous")


def _single_jacobian(model: pin.Model, data: pin.Data, frame: int, q: np.ndarray) -> np.ndarray:
    return pin.computeFrameJacobian(model, data, q, frame, pin.LOCAL_WORLD_ALIGNED).copy()


def fk(q: Any) -> Any:
    """Position of tool0.

    Parameters
    ----------
    q : (..., 6) float array_like or torch.Tensor, rad
        Joint angles, joints 1-6.

    Returns
    -------
    p : (..., 3) float, m, ``base_link`` frame
        ndarray for array input (``(6,)`` gives ``(3,)``); a tensor of the same dtype and device
        for tensor input.

    Raises
    ------
    ValueError
        When the last dimension is not 6, an entry is NaN or infinite, or ``q`` is not real
        (complex, strings): every public function of ur5kin refuses such input rather than
        propagating NaN or dropping an imaginary part.
    """
    return _dispatch(q, closed_form.position, (3,), _single_position)


def fk_world(q: Any, base_height: float) -> np.ndarray:
    """Position of tool0 in the task world (base at (0, 0, ``base_height``), :mod:`ur5kin.world`).

    Parameters
    ----------
    q : (..., 6) float array_like, rad
    base_height : float, m

    Returns
    -------
    p : (..., 3) float, m, world frame
    """
    return to_world(fk(np.asarray(q, dtype=float)), base_height)


def fk_pose(q: Any) -> Any:
    """Pose of tool0.

    Parameters
    ----------
    q : (..., 6) float array_like or torch.Tensor, rad

    Returns
    -------
    T : (..., 4, 4) float
        Homogeneous transform of tool0 in ``base_link`` (translation in m).
    """
    return _dispatch(q, closed_form.tool_pose, (4, 4), _single_pose)


def link_poses(q: Any) -> Any:
    """Poses of every link and of tool0.

    Parameters
    ----------
    q : (..., 6) float array_like or torch.Tensor, rad

    Returns
    -------
    T : (..., 8, 4, 4) float
        Transforms in ``base_link`` of base_link, shoulder_link, upper_arm_link, forearm_link,
        wrist_1_link, wrist_2_link, wrist_3_link and tool0 (translation in m).
    """
    return _dispatch(q, closed_form.link_poses, (8, 4, 4))


def jacobian(q: Any) -> Any:
    """Geometric Jacobian of tool0.

    Parameters
    ----------
    q : (..., 6) float array_like or torch.Tensor, rad

    Returns
    -------
    J : (..., 6, 6) float
        ``[v; w] = J @ dq``: rows 0-2 give the linear velocity of the tool0 origin (m/s), rows
        3-5 the angular velocity (rad/s), both in ``base_link`` axes (Pinocchio's
        ``LOCAL_WORLD_ALIGNED``); columns are joints 1-6 (per rad/s).
    """
    return _dispatch(q, _batched_jacobian, (6, 6), _single_jacobian)


def _batched_jacobian(q: Any) -> Any:
    return closed_form.jacobian_from_poses(closed_form.link_poses(q))


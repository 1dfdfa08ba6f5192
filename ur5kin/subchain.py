"""Sub-chains: vary joints 1..n of the UR5 while joints n+1..6 stay at given angles."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ur5kin.checks import joint_array, joint_count
from ur5kin.kinematics import fk, jacobian


@dataclass(frozen=True)
class SubChain:
    """The UR5 with only joints 1..``n_joints`` moving (the paper's "n controlled joints").

    Parameters
    ----------
    n_joints : int
        Number of moving joints, 1-6; joints 1..n_joints move.
    start_q : (6,) float, rad
        The start pose (a task's ``start_q``): its entries n_joints+1..6 are the angles the
        held joints keep (the first ``n_joints`` entries are ignored: they are what the
        sub-chain varies).
    """

    n_joints: int
    start_q: tuple[float, ...]

    def __post_init__(self) -> None:
        n_joints = joint_count(self.n_joints)
        start_q = joint_array(self.start_q, "start_q")
        if start_q.shape != (6,):
            raise ValueError(f"start_q must have shape (6,) (rad); got shape {start_q.shape}")
        object.__setattr__(self, "n_joints", n_joints)
        object.__setattr__(self, "start_q", tuple(float(x) for x in start_q))

    def full(self, q_head: Any) -> np.ndarray:
        """Full configurations ``(..., 6)`` rad from the moving joints ``q_head (..., n)`` rad."""
        head = joint_array(q_head, "q_head", self.n_joints)
        out = np.empty((*head.shape[:-1], 6))
        out[...] = self.start_q
        out[..., : self.n_joints] = head
        return out

    def fk(self, q_head: Any) -> np.ndarray:
        """tool0 position ``(..., 3)`` m in ``base_link`` for ``q_head (..., n)`` rad."""
        return fk(self.full(q_head))

    def jacobian(self, q_head: Any) -> np.ndarray:
        """Geometric Jacobian ``(..., 6, n)`` of tool0 for the moving joints (see ``jacobian``)."""
        return jacobian(self.full(q_head))[..., : self.n_joints]

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
    q_rest : (6,) float, rad
        Full configuration whose entries n_joints+1..6 hold the fixed joints (the first
        ``n_joints`` entries are ignored: they are what the sub-chain varies).
    """

    n_joints: int
    q_rest: tuple[float, ...]

    def __post_init__(self) -> None:
        n_joints = joint_count(self.n_joints)
        rest = joint_array(self.q_rest, "q_rest")
        if rest.shape != (6,):
            raise ValueError(f"q_rest must have shape (6,); got shape {rest.shape}")
        object.__setattr__(self, "n_joints", n_joints)
        object.__setattr__(self, "q_rest", tuple(float(x) for x in rest))

    def full(self, q_head: Any) -> np.ndarray:
        """Full configurations ``(..., 6)`` rad from the moving joints ``q_head (..., n)`` rad."""
        head = joint_array(q_head, "q_head", self.n_joints)
        out = np.empty((*head.shape[:-1], 6))
        out[...] = self.q_rest
        out[..., : self.n_joints] = head
        return out

    def fk(self, q_head: Any) -> np.ndarray:
        """tool0 position ``(..., 3)`` m in ``base_link`` for ``q_head (..., n)`` rad."""
        return fk(self.full(q_head))

    def jacobian(self, q_head: Any) -> np.ndarray:
        """Geometric Jacobian ``(..., 6, n)`` of tool0 for the moving joints (see ``jacobian``)."""
        return jacobian(self.full(q_head))[..., : self.n_joints]

"""DDPG (and TD3, SAC) + Hindsight Experience Replay in PyTorch (see docs/design.md).

K independent agents train in one process through stacked networks; ``python -m
ddpg_her.train`` runs the paper's protocol, and `load` returns a trained policy for analysis.
"""

from ddpg_her.config import AgentConfig, Algo, Exploration, HERStrategy

__all__ = ["EVAL_COLUMNS", "AgentConfig", "Algo", "Exploration", "HERStrategy", "TrainedPolicy",
           "load"]


def __getattr__(name: str):
    # torch loads only when needed, so that `python -m ddpg_her.train --help` answers at once.
    if name == "EVAL_COLUMNS":
        from ddpg_her.runfolder import EVAL_COLUMNS

        return EVAL_COLUMNS
    if name in ("TrainedPolicy", "load"):
        from ddpg_her import run

        return getattr(run, name)
    raise AttributeError(f"module 'ddpg_her' has no attribute {name!r}")

"""The K agents' episodes: rollout, exploration, HER storage and test sessions, written once.

One `Collector` serves every env backend through the envs' one tensor interface (`HostEnvs`
for Gymnasium's envs on the host, `TorchGoalVecEnv` for the tensor twin on the device; see
`ddpg_her.vecenv`). What the backends keep apart is only what makes a seed's run what it always
was: where the exploration noise is drawn (`ddpg_her.exploration`), and the host's numpy sums
(normaliser, test returns) against the device's, which read back only the logged numbers.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from ddpg_her.buffer import (
    Layout,
    ReplayBuffer,
    TensorEpisodes,
    her_goal_steps,
    her_tensors,
    pack_tensors,
)
from ddpg_her.config import AgentConfig
from ddpg_her.exploration import Explorer, NumpyDraws, TorchDraws
from ddpg_her.spaces import goal_input
from ddpg_her.vecenv import HostEnvs, TorchGoalVecEnv

ENV_BACKENDS = ("numpy", "batched", "torch")
"""The trainer's ``--env-backend``: ``numpy``, Gymnasium's envs on the host, one group of copies
per agent; ``batched``, the same envs merged where the tasks differ only in their goals
(``GoalVecEnv(merge=True)``); ``torch``, the env id's tensor twin on the trainer's device
(`TorchGoalVecEnv`). What each keeps equal: ``python -m ddpg_her.train --help``."""

ENV_DYNAMICS = ("torch", "numba")
"""The arm dynamics of the ``torch`` env backend (``envs.torchreach.DYNAMICS``, the trainer's
``--env-dynamics``): ``torch``, the vectorised tensor step; ``numba``, the numba kernels."""

Envs = HostEnvs | TorchGoalVecEnv

Policy = Callable[[dict[str, torch.Tensor], torch.Tensor], torch.Tensor]
"""``policy(obs, active) -> action``: obs tensors (N, ...), active (N,) bool -> (N, act_dim)
float64 action in env units on the envs' device (rows of copies not active are ignored)."""


def make_envs(env_backend: str, env_id: str, per_agent: Sequence[dict[str, Any]], copies: int,
              device: torch.device, env_dynamics: str = "torch") -> Envs:
    """``copies`` copies per agent of ``env_id`` in the env backend ``env_backend``, the
    ``torch`` backend's arm by ``env_dynamics`` (one of `ENV_DYNAMICS`; ValueError for another,
    or for ``numba`` with a host backend)."""
    if env_dynamics not in ENV_DYNAMICS:
        raise ValueError(f"env_dynamics must be one of {list(ENV_DYNAMICS)}; got "
                         f"{env_dynamics!r}")
    if env_backend == "torch":
        return TorchGoalVecEnv(env_id, per_agent, copies, device=device,
                               dynamics=None if env_dynamics == "torch" else env_dynamics)
    if env_dynamics != "torch":
        raise ValueError(f"env_dynamics={env_dynamics!r} is the dynamics of the torch env "
                         f"backend; got env_backend={env_backend!r}")
    return HostEnvs(env_id, per_agent, copies, merge=env_backend == "batched")


def rollout(envs: Envs, policy: Policy, seeds: Sequence[int]) -> TensorEpisodes:
    """One episode in each of the N copies, in lockstep, on the envs' device.

    On the host the rollout stops once every episode has ended; on the device all
    ``max_steps`` steps run (copies whose episode ended are stepped and ignored), since asking
    whether any copy still runs would read the device.
    """
    n, t_max, dev = envs.num_envs, envs.max_steps, envs.device
    obs = envs.reset(seeds)
    f64 = {"dtype": torch.float64, "device": dev}
    o = torch.zeros((n, t_max + 1, envs.obs_dim), **f64)
    ag = torch.zeros((n, t_max + 1, envs.goal_dim), **f64)
    a = torch.zeros((n, t_max, envs.scale.dim), **f64)
    r = torch.zeros((n, t_max), **f64)
    term = torch.zeros((n, t_max), dtype=torch.bool, device=dev)
    length = torch.zeros(n, dtype=torch.long, device=dev)
    success = torch.zeros(n, dtype=torch.bool, device=dev)
    o[:, 0], ag[:, 0] = obs["observation"], obs["achieved_goal"]
    goal = obs["desired_goal"].clone()
    active = torch.ones(n, dtype=torch.bool, device=dev)
    for t in range(t_max):
        action = policy(obs, active).to(torch.float64)
        obs, reward, terminated, truncated, succ = envs.step(action, active, obs)
        o[:, t + 1], ag[:, t + 1] = obs["observation"], obs["achieved_goal"]
        a[:, t] = torch.where(active.unsqueeze(-1), action, 0.0)
        r[:, t], term[:, t] = reward, terminated
        length += active
        success = torch.where(active, succ, success)
        active = active & ~(terminated | truncated)
        if envs.on_host and not active.any():
            break
    if envs.on_host and active.any():
        raise RuntimeError(f"episodes still running after the time limit of {t_max} steps")
    return TensorEpisodes(observation=o, achieved_goal=ag, desired_goal=goal, action=a,
                          reward=r, terminated=term, length=length, success=success)


class Collector:
    """Training episodes and test sessions of K agents in one env backend.

    envs : one copy per agent (training), eval_envs : ``config.eval_episodes`` copies per agent
    (tests), both of one backend; rngs : (K,) numpy generators (HER goals, and on the host the
    exploration noise); generators : (K,) torch generators of the exploration noise on the
    device (``torch`` backend); device, dtype : the agents' (their networks' inputs).
    """

    def __init__(self, envs: Envs, eval_envs: Envs, config: AgentConfig,
                 rngs: Sequence[np.random.Generator], generators: Sequence[torch.Generator],
                 *, device: torch.device, dtype: torch.dtype):
        self.envs, self.eval_envs, self.config, self.rngs = envs, eval_envs, config, rngs
        self.device, self.dtype = device, dtype
        self.k, self.scale = len(rngs), envs.scale
        self.layout = Layout(envs.obs_dim + 2 * envs.goal_dim, envs.scale.dim)
        draws = NumpyDraws(rngs) if envs.on_host else TorchDraws(generators, envs.device)
        self.explorer = Explorer(config, draws, self.k, envs.scale.dim)

    def _inputs(self, obs: dict[str, torch.Tensor], m: int) -> torch.Tensor:
        """Observations of K * m copies (agent-major) -> network input (K, m, in_dim)."""
        x = goal_input(obs["observation"], obs["achieved_goal"], obs["desired_goal"])
        return x.reshape(self.k, m, -1).to(self.device, self.dtype)

    def train_episode(self, agent: Any, buffer: ReplayBuffer, seeds: Sequence[int],
                      warm: bool) -> tuple[np.ndarray, np.ndarray]:
        """One exploring episode per agent (uniformly random actions while ``warm``), stored
        with its HER copies in ``buffer``; returns the episodes' lengths and successes (K,).

        On the device the host reads, per episode, the K lengths and successes, the lengths
        of the HER copies and the normaliser's sums; transitions never leave the device.
        """
        envs, dev = self.envs, self.envs.device
        self.explorer.reset()

        def policy(obs: dict[str, torch.Tensor], active: torch.Tensor) -> torch.Tensor:
            u = torch.zeros((self.k, self.scale.dim), dtype=torch.float64, device=dev) if warm \
                else agent.act(self._inputs(obs, 1), explore=True)[:, 0].double().to(dev)
            return self.scale.to_env(self.explorer(u, active, uniform=warm))

        eps = rollout(envs, policy, seeds)
        flags = torch.stack([eps.length, eps.success.long()]).cpu().numpy()
        length, success = flags[0], flags[1].astype(bool)
        steps = [her_goal_steps(self.config.her_strategy, int(length[k]), self.config.her_k,
                                self.rngs[k]) for k in range(self.k)]
        rows = [pack_tensors(eps.observation[k], eps.achieved_goal[k], eps.desired_goal[k],
                             eps.action[k], eps.reward[k], eps.terminated[k],
                             self.scale)[:length[k]] for k in range(self.k)]
        # one relabelling call per agent, its reward being the agent's task
        her = [(k, her_tensors(eps, np.full(len(g), k), g,
                               functools.partial(envs.reward_fn, group=k),
                               functools.partial(envs.terminated_fn, group=k)))
               for k, g in enumerate(steps) if len(g)]
        her_lengths = iter(torch.cat([out[3] for _, out in her]).tolist() if her else [])
        copies: list[list[torch.Tensor]] = [[] for _ in range(self.k)]
        for k, (goal, reward, terminated, _) in her:
            idx = torch.full((len(goal),), k, device=dev)
            packed = pack_tensors(eps.observation[idx], eps.achieved_goal[idx], goal,
                                  eps.action[idx], reward, terminated, self.scale)
            copies[k] = [p[:next(her_lengths)] for p in packed]
        for k in range(self.k):
            all_rows = torch.cat([rows[k], *copies[k]])
            buffer.put(k, int(buffer.total[k]), all_rows)
            inputs = all_rows[:, :self.layout.in_dim]
            # the host's statistics are numpy's sums, the device's torch's (read back once)
            agent.normalizer.update(k, inputs.numpy() if envs.on_host else inputs)
        return length, success

    def test_session(self, agent: Any, seeds: Sequence[int]
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``eval_episodes`` deterministic episodes per agent from ``seeds`` (K * m, agent-
        major); returns their successes, returns and final distances (m), (K * m,) each."""
        envs, m = self.eval_envs, self.config.eval_episodes

        def policy(obs: dict[str, torch.Tensor], active: torch.Tensor) -> torch.Tensor:
            u = agent.act(self._inputs(obs, m)).reshape(self.k * m, -1)
            return self.scale.to_env(u.double().to(envs.device))

        eps = rollout(envs, policy, seeds)
        n = torch.arange(len(eps.length), device=envs.device)
        miss = eps.achieved_goal[n, eps.length] - eps.desired_goal
        if envs.on_host:  # numpy's sums, episode by episode, as the host always summed
            returns = [eps.reward[i, :eps.length[i]].numpy().sum() for i in n]
            distance = [np.linalg.norm(x) for x in miss.numpy()]
            return eps.success.numpy(), np.array(returns), np.array(distance)
        logged = torch.stack([eps.success.double(), eps.reward.sum(-1),
                              torch.linalg.vector_norm(miss, dim=-1)])
        success, returns, distance = logged.cpu().numpy()  # the one read of the session
        return success.astype(bool), returns, distance

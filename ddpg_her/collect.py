"""The K agents' episodes: rollout, exploration, HER storage and test sessions, written once.

One `Collector` serves the host env backends (``numpy``, ``batched``) through the envs' tensor
interface (`HostEnvs`, see `ddpg_her.vecenv`): the exploration noise drawn by numpy generators
(`ddpg_her.exploration`), the normaliser's and the test returns' sums numpy's. The training
program (``--env-backend program``) keeps its episodes on the device: ``ddpg_her.program``.
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
from ddpg_her.exploration import Explorer, NumpyDraws
from ddpg_her.spaces import goal_input
from ddpg_her.vecenv import HostEnvs

ENV_BACKENDS = ("numpy", "batched")
"""The trainer's ``--env-backend``: ``numpy``, Gymnasium's envs on the host, one group of copies
per agent; ``batched``, the same envs merged where the tasks differ only in their goals
(``GoalVecEnv(merge=True)``). What each keeps equal: ``python -m ddpg_her.train --help``.
(``program``, the training program, is not a `Trainer`'s: ``ddpg_her.program``.)"""

Policy = Callable[[dict[str, torch.Tensor], torch.Tensor], torch.Tensor]
"""``policy(obs, active) -> action``: obs tensors (N, ...), active (N,) bool -> (N, act_dim)
float64 action in env units on the envs' device (rows of copies not active are ignored)."""


def make_envs(env_backend: str, env_id: str, per_agent: Sequence[dict[str, Any]],
              copies: int) -> HostEnvs:
    """``copies`` copies per agent of ``env_id`` in the env backend ``env_backend`` (one of
    `ENV_BACKENDS`; ValueError for another)."""
    if env_backend not in ENV_BACKENDS:
        raise ValueError(f"env_backend must be one of {list(ENV_BACKENDS)}; got "
                         f"{env_backend!r}")
    return HostEnvs(env_id, per_agent, copies, merge=env_backend == "batched")


def rollout(envs: HostEnvs, policy: Policy, seeds: Sequence[int]) -> TensorEpisodes:
    """One episode in each of the N copies, in lockstep, on the host; the rollout stops once
    every episode has ended."""
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
        if not active.any():
            break
    if active.any():
        raise RuntimeError(f"episodes still running after the time limit of {t_max} steps")
    return TensorEpisodes(observation=o, achieved_goal=ag, desired_goal=goal, action=a,
                          reward=r, terminated=term, length=length, success=success)


class Collector:
    """Training episodes and test sessions of K agents in one env backend.

    envs : one copy per agent (training), eval_envs : ``config.eval_episodes`` copies per agent
    (tests), both of one backend; rngs : (K,) numpy generators (HER goals and the exploration
    noise); device, dtype : the agents' (their networks' inputs).
    """

    def __init__(self, envs: HostEnvs, eval_envs: HostEnvs, config: AgentConfig,
                 rngs: Sequence[np.random.Generator], *, device: torch.device, dtype: torch.dtype):
        self.envs, self.eval_envs, self.config, self.rngs = envs, eval_envs, config, rngs
        self.device, self.dtype = device, dtype
        self.k, self.scale = len(rngs), envs.scale
        self.layout = Layout(envs.obs_dim + 2 * envs.goal_dim, envs.scale.dim)
        self.explorer = Explorer(config, NumpyDraws(rngs), self.k, envs.scale.dim)

    def _inputs(self, obs: dict[str, torch.Tensor], m: int) -> torch.Tensor:
        """Observations of K * m copies (agent-major) -> network input (K, m, in_dim)."""
        x = goal_input(obs["observation"], obs["achieved_goal"], obs["desired_goal"])
        return x.reshape(self.k, m, -1).to(self.device, self.dtype)

    def train_episode(self, agent: Any, buffer: ReplayBuffer, seeds: Sequence[int],
                      warm: bool) -> tuple[np.ndarray, np.ndarray]:
        """One exploring episode per agent (uniformly random actions while ``warm``), stored
        with its HER copies in ``buffer``; returns the episodes' lengths and successes (K,)."""
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
            agent.normalizer.update(k, inputs.numpy())  # numpy's sums, as the host always summed
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
        # numpy's sums, episode by episode, as the host always summed
        returns = [eps.reward[i, :eps.length[i]].numpy().sum() for i in n]
        distance = [np.linalg.norm(x) for x in miss.numpy()]
        return eps.success.numpy(), np.array(returns), np.array(distance)

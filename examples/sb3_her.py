"""Stable-Baselines3's DDPG + HER on UR5Reach-v0, written as a user would: the env as given.

    python examples/sb3_her.py --region farbox --joints 3 --timesteps 20000

What SB3 needs, and why: UR5Reach-v0 is a Gymnasium goal env (dict observation with
``achieved_goal`` and ``desired_goal``, a vectorised ``compute_reward``), so SB3's
``MultiInputPolicy`` and ``HerReplayBuffer`` take it as it is. The paper's dense reward (eq. 2)
charges the action, ``-|a|^2``, and HER recomputes the rewards of relabelled transitions with
``env.compute_reward(achieved, desired, info)``: the action comes from the step's ``info``,
which SB3's buffer keeps only with ``copy_info_dict=True`` (without it the env says so and
stops). ``reward_type="sparse"`` needs no info. For the project's own protocol (test
sessions, run folders, Table I's hyperparameters) use ``python -m analysis.sb3``.
"""

from __future__ import annotations

import argparse

import gymnasium
import numpy as np
from stable_baselines3 import DDPG, HerReplayBuffer
from stable_baselines3.common.noise import NormalActionNoise

import envs  # noqa: F401  (registers UR5Reach-v0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--region", default="farbox", help="goal region (default: farbox)")
    parser.add_argument("--joints", type=int, default=3, help="controlled joints, 2-6 "
                                                              "(default: 3)")
    parser.add_argument("--timesteps", type=int, default=20_000,
                        help="env steps of training, >= 1 (100 steps per episode; default: "
                             "20000)")
    parser.add_argument("--test-episodes", type=int, default=20,
                        help="test episodes of the deterministic policy afterwards, >= 1 "
                             "(default: 20)")
    parser.add_argument("--seed", type=int, default=0, help="seed, >= 0 (default: 0)")
    args = parser.parse_args(argv)

    env = gymnasium.make("UR5Reach-v0", region=args.region, n_joints=args.joints)
    act_dim = env.action_space.shape[0]
    model = DDPG(
        "MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs={"goal_selection_strategy": "final", "n_sampled_goal": 4,
                              "copy_info_dict": True},  # the dense reward's action
        action_noise=NormalActionNoise(np.zeros(act_dim), np.full(act_dim, 0.1)),
        learning_starts=min(1_000, args.timesteps // 2), batch_size=64, gamma=0.98,
        policy_kwargs={"net_arch": [400, 300]}, seed=args.seed, device="cpu", verbose=0)
    model.learn(total_timesteps=args.timesteps, progress_bar=False)

    reached = 0
    for episode in range(args.test_episodes):
        obs, info = env.reset(seed=10_000 + episode)
        done = False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        reached += bool(info["is_success"])
    print(f"{reached} of {args.test_episodes} test goals reached after {args.timesteps} steps")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

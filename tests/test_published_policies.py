"""The policies committed under results/ (issue 43): results/policies and the reported claims
runs' own folders (results/claims/UNIT/runs/sSEED); small, read by ``ddpg_her.load``, replayed
and mapped straight from results/, and as good as their own eval.csv says."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from cli_tools import ROOT

POLICIES = sorted(p.parent.parent for pattern in ("policies/*", "claims/*/runs/s*")
                  for p in (ROOT / "results").glob(f"{pattern}/checkpoints/episode-*.pt"))


def test_the_published_policies_are_there():
    names = {str(p.relative_to(ROOT / "results")) for p in POLICIES}
    assert {"policies/farbox-j3-s0", "policies/program-farbox-j3-s0", "claims/per/runs/s0",
            "claims/sparse/runs/s0"} <= names, names


@pytest.mark.parametrize("run", POLICIES, ids=[str(p.relative_to(ROOT)) for p in POLICIES])
def test_a_published_policy_is_small_loads_and_reaches_what_its_eval_csv_says(run: Path):
    """The reference is the trainer's own last test session (its eval.csv: 100 goals of the
    task, through the trainer's collector); here 200 goals of the same sampler through
    success_map's batched evaluation, a second path. They agree within 10 per 100 (the
    binomial spread of the two samples at the rates seen, about 3-4 per 100, three times)."""
    import torch

    from analysis.success_map import evaluate
    from ddpg_her import load
    from ddpg_her.runfolder import RunFolder
    from envs.task import task_sampler

    (checkpoint,) = (run / "checkpoints").glob("episode-*.pt")
    assert checkpoint.stat().st_size < 1_000_000  # the actor and normaliser alone
    state = torch.load(checkpoint, weights_only=True)
    assert set(state) == {"episode", "agent"} and set(state["agent"]) == {"actor", "normalizer"}
    assert not (run / "buffer").exists()
    policy = load(run)
    last = RunFolder(run).read_eval()[-1]
    assert policy.episode == int(last["episode"])
    goals = task_sampler(policy.task).sample(200, np.random.default_rng(7)).goals
    reached = evaluate(policy, policy.task, goals, batch=200, progress=False)
    recorded = int(last["successes"]) / int(last["tests"])
    assert abs(reached.mean() - recorded) <= 0.10, (reached.mean(), recorded)


def test_the_far_box_policy_replays_and_maps_from_results(tmp_path: Path):
    from analysis import replay, success_map

    run = ROOT / "results" / "policies" / "farbox-j3-s0"
    assert replay.main([str(run), "--episodes", "2", "--out", str(tmp_path / "r.html"),
                        "--no-progress"]) == 0
    assert (tmp_path / "r.html").stat().st_size > 100_000
    assert success_map.main([str(run), "--goals", "100", "--z", "0.1", "0.3", "--out",
                             str(tmp_path / "m.png"), "--no-progress"]) == 0
    assert (tmp_path / "m.png").stat().st_size > 10_000

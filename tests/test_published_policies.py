"""The policies committed under results/ (issue 43): results/policies and the reported runs'
own folders (results/claims/UNIT/runs/sSEED, results/paper_long/runs/SETTING/sSEED); small,
read by ``ddpg_her.load``, replayed and mapped straight from results/, and as good as their own
eval.csv says."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from cli_tools import ROOT

POLICIES = sorted(p.parent.parent
                  for pattern in ("policies/*", "claims/*/runs/s*", "paper_long/runs/*/s*")
                  for p in (ROOT / "results").glob(f"{pattern}/checkpoints/episode-*.pt"))


def test_the_published_policies_are_there():
    names = {str(p.relative_to(ROOT / "results")) for p in POLICIES}
    assert {"policies/farbox-j3-s0", "policies/program-farbox-j3-s0", "claims/per/runs/s0",
            "claims/sparse/runs/s0", "paper_long/runs/unconstrained-j3/s0",
            "paper_long/runs/zheight-j3/s0", "paper_long/runs/closebox-j3/s0"} <= names, names


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


def test_publish_adds_a_policy_to_the_committed_copy_of_the_same_run_only(tiny_ur5_run: Path,
                                                                        tmp_path: Path):
    """examples/publish_policy.py: into a new folder it writes spec, eval.csv and the policy,
    which `ddpg_her.load` reads as the run's own; into the committed copy of the same run (a
    retrained stage: its spec.json differs in ``created`` alone, its eval.csv in ``wall_s``)
    it adds the checkpoint and keeps the committed files; another run's copy (another seed,
    another test session), or one published already, is refused."""
    import json
    import shutil
    import sys

    import torch

    from ddpg_her import load

    sys.path.insert(0, str(ROOT / "examples"))
    from publish_policy import publish

    fresh = publish(tiny_ur5_run, tmp_path / "new")
    assert fresh.parent.parent == tmp_path / "new"
    mine, theirs = load(tmp_path / "new"), load(tiny_ur5_run)
    assert mine.episode == theirs.episode
    obs = {"observation": np.linspace(-1, 1, 9), "achieved_goal": np.array([0.4, 0.1, 0.2]),
           "desired_goal": np.array([0.5, 0.2, 0.3])}
    assert np.array_equal(mine(obs), theirs(obs))

    committed = tmp_path / "committed"
    committed.mkdir()
    spec = json.loads((tiny_ur5_run / "spec.json").read_text())
    written = json.dumps({**spec, "created": "2020-01-01T00:00:00+00:00"})
    (committed / "spec.json").write_text(written)
    lines = (tiny_ur5_run / "eval.csv").read_text().splitlines()
    assert lines[0].endswith(",wall_s")
    timed = "\n".join([lines[0]] + [row.rsplit(",", 1)[0] + ",1234.5" for row in lines[1:]])
    (committed / "eval.csv").write_text(timed + "\n")
    added = publish(tiny_ur5_run, committed)
    assert (committed / "spec.json").read_text() == written  # the committed record stays
    assert (committed / "eval.csv").read_text() == timed + "\n"
    a, b = (torch.load(f)["agent"]["actor"] for f in (added, fresh))
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    with pytest.raises(FileExistsError, match="published checkpoint already"):
        publish(tiny_ur5_run, committed)

    other = tmp_path / "other"
    other.mkdir()
    (other / "spec.json").write_text(json.dumps({**spec, "seed": spec["seed"] + 1}))
    shutil.copyfile(tiny_ur5_run / "eval.csv", other / "eval.csv")
    with pytest.raises(FileExistsError, match="holds another run"):
        publish(tiny_ur5_run, other)
    assert not (other / "checkpoints").exists()
    (other / "spec.json").write_text(written)  # the same run's spec, another test session
    (other / "eval.csv").write_text(timed.replace(",0,", ",1,", 1) + "\n")
    with pytest.raises(FileExistsError, match="holds another run"):
        publish(tiny_ur5_run, other)

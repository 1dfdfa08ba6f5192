"""analysis.optimality: IK branches, returns against a plain env loop, reward-reading limits."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from cli_tools import run_module

import envs
import regions
import ur5kin
from analysis import optimality as opt
from envs.spec import TaskSpec

pytestmark = pytest.mark.xdist_group("test_optimality")
"""Under pytest-xdist one worker runs this module, so that the two settings' simulations are run
once."""

GOALS = 12
SEED = 3
GAMMA = 0.98
ROOT = Path(__file__).parent.parent


@pytest.fixture(scope="module")
def zheight() -> opt.Simulation:
    """A constrained-start setting: the action penalty decides most of its goals."""
    return opt.simulate(TaskSpec(region="zheight", n_joints=3), GOALS, SEED)


@pytest.fixture(scope="module")
def planar() -> opt.Simulation:
    return opt.simulate(TaskSpec(region="unconstrained", n_joints=2), GOALS, SEED)


@pytest.mark.parametrize(("region", "n"), [("zheight", 3), ("unconstrained", 2),
                                           ("farbox", 6), ("closebox", 4)])
def test_ik_branches_put_tool0_at_the_goal(region: str, n: int) -> None:
    task = TaskSpec(region=region, n_joints=n)
    goals, q = opt.env_goals(task, 8, SEED)
    branches = opt.ik_branches(task, goals, q)
    have = ~np.isnan(branches[..., 0])
    assert have[:, 0].all()
    full = np.broadcast_to(np.asarray(task.start_q), (*branches.shape[:2], 6)).copy()
    full[..., :n] = branches
    tool = ur5kin.fk(np.nan_to_num(full)) + np.array([0.0, 0.0, task.base_height])  # world
    np.testing.assert_allclose(tool[have], np.broadcast_to(goals[:, None], tool.shape)[have],
                               atol=1e-8)
    assert np.all(np.abs(branches[have]) <= np.pi)  # wrapped into the action range
    # the goal's own sampled configuration is one of the branches
    assert all(np.abs(ur5kin.wrap(branches[i, have[i]] - q[i, :n])).max(-1).min() < 1e-9
               for i in range(len(goals)))
    counts = have.sum(axis=1)
    if n == 2:  # pan x 1 elbow: the elbow is held at the start angle
        assert counts.min() >= 1 and counts.max() <= 2
    elif n == 3:  # 2 pans x 2 elbows, one of them the sampled configuration
        assert counts.min() >= 2 and counts.max() <= 4
    else:  # 4 with the start's wrist (if it reaches) and 4 with the sampled one (n = 6: + 8)
        assert counts.min() >= 4 and counts.max() <= (16 if n == 6 else 8)


def test_goals_are_the_envs(zheight: opt.Simulation) -> None:
    env = envs.BatchedReach(GOALS, task=zheight.task)
    obs, _ = env.reset(seed=SEED)
    np.testing.assert_array_equal(zheight.goals, obs["desired_goal"])


def _plain_return(task: TaskSpec, seed: int, command: np.ndarray) -> tuple[float, bool]:
    """Discounted return of one constant-command episode in gymnasium.make's env, by hand."""
    env = gymnasium.make("UR5Reach-v0", task=task)
    env.reset(seed=seed)
    total, discount, reached = 0.0, 1.0, False
    while True:
        _, reward, terminated, truncated, info = env.step(command)
        total += discount * reward
        discount *= GAMMA
        reached |= bool(info["is_success"])
        if terminated or truncated:
            env.close()
            return total, reached


@pytest.mark.parametrize("unit", ["command", "actor"])
def test_returns_match_a_plain_env_loop(zheight: opt.Simulation, unit: str) -> None:
    task = zheight.task.replace(action_penalty_unit=unit)
    result = opt.evaluate(zheight, task, GAMMA)
    n = task.n_joints
    checked_reach = checked_miss = 0
    for i in range(4):
        cases = [(zheight.branches[i, k], result.branch_returns[i, k],
                  result.branch_reached[i, k]) for k in range(zheight.branches.shape[1])
                 if not np.isnan(zheight.branches[i, k, 0])]
        cases += [(np.asarray(task.start_q[:n]), result.stay_return[i], result.stay_reached[i]),
                  (np.zeros(n), result.zero_return[i], result.zero_reached[i])]
        for command, expected, reached in cases[:3] + cases[-2:]:
            total, hit = _plain_return(task, SEED + i, command)
            assert total == pytest.approx(expected, rel=1e-6, abs=1e-6)
            assert hit == reached
            checked_reach += hit
            checked_miss += not hit
    assert checked_reach and checked_miss  # both episode ends were compared


def test_without_action_penalty_a_quick_reach_is_always_worth_it(zheight: opt.Simulation,
                                                                  planar: opt.Simulation) -> None:
    """With w = 0 the only costs are distances. Any tool-goal distance is below D = 2 r (both lie
    in the reach ball of radius r), so a candidate that succeeds at step k earns at least
    100 g^(k-1) - D (1 - g^k) / (1 - g), while holding without success earns < 0. Reaching is
    then worth it whenever that bound is positive: k <= k_max below. (It is not for every
    reachable goal: a constant command that arrives late, e.g. after sticking on the plane, can
    accumulate more distance cost than holding; the brief's stronger claim is false.)"""
    for sim in (zheight, planar):
        task = sim.task.replace(action_weight=0.0)
        result = opt.evaluate(sim, task, GAMMA)
        diameter = 2.0 * regions.reach_ball(task.base_height).radius
        k = np.arange(1, task.max_episode_steps + 1)
        bound = task.success_reward * GAMMA ** (k - 1) - diameter * (1 - GAMMA**k) / (1 - GAMMA)
        k_max = int(k[bound > 0].max())
        assert 20 < k_max < task.max_episode_steps
        steps = np.where(result.branch_reached, result.branch_steps, np.inf).min(axis=1)
        quick = steps <= k_max
        assert quick.sum() >= GOALS // 2
        assert result.worth[quick].all()
        floor = bound[np.minimum(steps, task.max_episode_steps).astype(int) - 1]
        assert np.all(result.best_reach_return[quick] >= floor[quick])
        assert np.all(result.best_hold_return < 0.0)


def test_a_huge_action_weight_makes_holding_win(zheight: opt.Simulation) -> None:
    """With w = 1e4 any command other than zero costs more than the bonus can repay, so the only
    goals worth reaching are those the zero (or start) command passes within the radius."""
    result = opt.evaluate(zheight, zheight.task.replace(action_weight=1e4), GAMMA)
    assert np.all(result.worth <= (result.zero_reached | result.stay_reached))
    assert result.share_worth <= 0.25
    assert opt.evaluate(zheight, zheight.task, GAMMA).share_worth > result.share_worth or \
        result.share_worth == 0.0


def test_actor_reading_differs_from_command_reading_by_the_penalty(zheight: opt.Simulation
                                                                   ) -> None:
    """Same motions, so the returns differ by exactly w (1 - 1/pi^2) |a|^2 sum_{t<L} g^t."""
    command = opt.evaluate(zheight, zheight.task, GAMMA)
    actor = opt.evaluate(zheight, zheight.task.replace(action_penalty_unit="actor"), GAMMA)
    have = ~np.isnan(zheight.branches[..., 0])
    a2 = np.square(zheight.branches).sum(axis=-1)
    horizon = (1 - GAMMA ** command.branch_steps) / (1 - GAMMA)
    expected = -zheight.task.action_weight * (1 - 1 / math.pi**2) * a2 * horizon
    np.testing.assert_allclose((command.branch_returns - actor.branch_returns)[have],
                               expected[have], rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(command.branch_reached, actor.branch_reached)
    # the constrained start's penalty dominates the command reading: far more goals pay off
    # under the actor's, for these goals (measured, not a theorem: shrinking every penalty
    # also helps holding the start pose)
    assert actor.share_worth > command.share_worth
    assert np.all(actor.worth >= command.worth)


def test_wilson_interval(zheight: opt.Simulation) -> None:
    result = opt.evaluate(zheight, zheight.task.replace(action_penalty_unit="actor"), GAMMA)
    n, p, z = result.n_goals, result.share_worth, 1.959963984540054
    center = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    assert result.share_worth_ci == pytest.approx((center - half, center + half), abs=1e-9)


def test_brute_force_search_bounds_and_mostly_agrees(planar: opt.Simulation) -> None:
    result = opt.evaluate(planar, planar.task, GAMMA)
    check = opt.brute_force(planar, planar.task, GAMMA, per_joint=9)
    assert check.commands.shape == (81, 2)
    assert np.all(check.best_reach_return >= result.best_reach_return)
    assert np.all(check.best_hold_return >= result.best_hold_return)
    # some grid command holds off the goal more cheaply than stay or zero: the grid was scored
    assert np.any(check.best_hold_return > result.best_hold_return)
    assert np.mean(check.worth == result.worth) >= 0.75


def test_bad_inputs_are_named(zheight: opt.Simulation) -> None:
    with pytest.raises(ValueError, match="position"):
        opt.simulate(TaskSpec(control_mode="velocity"), 2)
    with pytest.raises(ValueError, match=r"goals=0 \(expected an integer >= 1"):
        opt.simulate(TaskSpec(), 0)
    with pytest.raises(ValueError, match="gamma"):
        opt.evaluate(zheight, zheight.task, 1.5)
    with pytest.raises(ValueError, match="changes the motion"):
        opt.evaluate(zheight, zheight.task.replace(kp=tuple(0.5 * np.asarray(zheight.task.kp))))
    with pytest.raises(ValueError, match="per_joint"):
        opt.brute_force(zheight, per_joint=100)
    with pytest.raises(ValueError, match="unknown reading"):
        opt.reading_fields("gazebo")


def test_cli_writes_csv_and_figure(tmp_path: Path) -> None:
    proc = run_module("analysis.optimality", "--settings", "unconstrained:2", "--readings",
                      "ours", "actor_penalty", "compliant", "--goals", "4", "--grid", "3",
                      "--no-progress", "--out", str(tmp_path), cwd=ROOT, timeout=300)
    with open(tmp_path / "optimality.csv") as f:
        rows = list(csv.DictReader(f))
    has_compliant = not opt.missing_fields(opt.READINGS["compliant"])
    assert [r["reading"] for r in rows] == ["ours", "actor_penalty"] + \
        (["compliant"] if has_compliant else [])
    assert has_compliant or "compliant" in proc.stderr
    assert rows[0]["goals"] == "4" and rows[0]["grid_per_joint"] == "3"
    assert float(rows[1]["share_worth"]) >= float(rows[0]["share_worth"])
    assert (tmp_path / "optimality.png").stat().st_size > 0
    assert "lower" in proc.stdout or "below" in proc.stdout


def test_the_plot_draws_a_missing_grid_check_as_nothing_and_refuses_a_missing_share(tmp_path):
    """An empty ``share_worth_grid`` is a grid check that was not run (nothing drawn); an empty
    share or interval is a broken row, refused, never drawn as a silent gap."""
    row = {"region": "farbox", "joints": 3, "reading": "ours", "share_worth": "0.5",
           "ci_low": "0.4", "ci_high": "0.6", "share_reachable": "0.7", "share_worth_grid": ""}
    ax = opt.plot([row, {**row, "region": "zheight", "share_worth_grid": "0.3"}],
                  out=tmp_path / "ok.png")
    grid = [c for c in ax.collections if c.get_label().startswith("grid")]
    heights = np.ma.filled(grid[0].get_offsets()[:, 1].astype(float), np.nan)  # % of goals
    assert len(grid) == 1 and np.isnan(heights).tolist() == [True, False]
    assert heights[1] == pytest.approx(30.0)
    for key in ("share_worth", "ci_low", "ci_high", "share_reachable"):
        with pytest.raises(ValueError, match="could not convert"):
            opt.plot([{**row, key: ""}], out=tmp_path / f"{key}.png")


@pytest.mark.parametrize("task, message", [
    (["nosuch=1"], "--task nosuch: TaskSpec has no field 'nosuch'"),
    (["region=zheight"], "--task region: the study sets it for every setting"),
    (["n_joints=3"], "--task n_joints: the study sets it for every setting"),
    (["action_penalty_unit=command"],
     "--task action_penalty_unit: the reading(s) actor_penalty set it themselves"),
    (["action_weight=0.5", "action_weight=0.7"],
     "give the task field 'action_weight' two values (0.5, 0.7)"),
    (["action_weight=-1"], "--task: "),
    ([], "--curves: "),
])
def test_task_overrides_are_checked_in_our_words_before_any_computing(tmp_path, capsys, task,
                                                                      message):
    """Issue 37, kinds 2, 4 and 7: an unknown key or region/n_joints went to TaskSpec(...) as a
    TypeError traceback after the run started, a key a reading sets was overruled by the
    reading without a word, and a missing --curves folder was found after the computation."""
    args = [a for t in task for a in ("--task", t)] or ["--curves", str(tmp_path / "nosuch")]
    with pytest.raises(SystemExit) as exit_:
        opt.main(["--settings", "unconstrained:2", "--goals", "2", "--readings", "ours",
                  "actor_penalty", "--out", str(tmp_path / "o"), "--no-progress", *args])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err, err
    assert not (tmp_path / "o" / "optimality.csv").exists()


@pytest.mark.parametrize("content", [None, "{", "region,joints\nfarbox,3\n",
                                     ",".join(opt.CSV_COLUMNS) + "\n"],
                         ids=["missing", "not_csv", "other_columns", "no_rows"])
def test_from_csv_refuses_what_is_not_an_optimality_csv_naming_it(tmp_path, capsys, content):
    """Issue 37, kind 7 (found by benchmarks/reliability_probe.py): ``--from-csv`` of a missing
    file ended in a FileNotFoundError traceback, and of a file that is not an optimality.csv
    wrote empty outputs ("joined 0 rows") and exited 0."""
    path = tmp_path / "in.csv"
    if content is not None:
        path.write_text(content)
    with pytest.raises(SystemExit) as stop:
        opt.main(["--from-csv", str(path), "--out", str(tmp_path / "o")])
    assert stop.value.code == 2
    assert f"--from-csv {path}" in capsys.readouterr().err
    assert not (tmp_path / "o" / "optimality.csv").exists()

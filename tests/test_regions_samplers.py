"""Goal samplers: goals in the region, reached by their configuration, seeded, failing fast."""

from __future__ import annotations

import json

import numpy as np
import pytest

import regions
import ur5kin
from regions import (
    CONSTRAINED_START,
    UNCONSTRAINED_START,
    CartesianSampler,
    JointSpaceSampler,
    UnreachableRegionError,
    sampler_from_dict,
)

H = regions.DEFAULT_BASE_HEIGHT
CASES = [("unconstrained", UNCONSTRAINED_START), ("zheight", CONSTRAINED_START),
         ("closebox", CONSTRAINED_START), ("farbox", CONSTRAINED_START),
         ("farbox_tall", CONSTRAINED_START)]


def _check_batch(batch: regions.GoalBatch, region: regions.Region, n_joints: int,
                 start_q: tuple[float, ...], n: int) -> None:
    assert batch.goals.shape == (n, 3) and batch.q.shape == (n, 6)
    assert region.contains(batch.goals).all()
    reached = ur5kin.fk(batch.q) + np.array([0.0, 0.0, H])
    assert np.abs(reached - batch.goals).max() < 1e-9
    assert ur5kin.plane_clear(batch.q, H).all()
    # Held joints stay at their start angles; moving joints stay in [-pi, pi].
    np.testing.assert_array_equal(batch.q[:, n_joints:], np.broadcast_to(
        np.asarray(start_q)[n_joints:], (n, 6 - n_joints)))
    assert np.abs(batch.q).max() <= np.pi


@pytest.mark.parametrize(("name", "start_q"), CASES)
@pytest.mark.parametrize("n_joints", [2, 3, 6])
def test_joint_space_goals_are_in_region_reached_and_clear(name, start_q, n_joints) -> None:
    region = regions.get(name)
    sampler = JointSpaceSampler(region, n_joints, start_q)
    batch = sampler.sample(300, np.random.default_rng(1))
    _check_batch(batch, region, n_joints, start_q, 300)
    assert batch.proposals >= 300 and 300 <= batch.in_region <= batch.proposals


@pytest.mark.parametrize(("name", "start_q"), CASES)
@pytest.mark.parametrize("n_joints", [3, 5])
def test_cartesian_goals_are_in_region_reached_and_clear(name, start_q, n_joints) -> None:
    region = regions.get(name)
    batch = CartesianSampler(region, n_joints, start_q).sample(200, np.random.default_rng(2))
    _check_batch(batch, region, n_joints, start_q, 200)


@pytest.mark.parametrize("cls", [JointSpaceSampler, CartesianSampler])
def test_same_seed_same_goals(cls) -> None:
    sampler = cls(regions.get("farbox"), 3, CONSTRAINED_START)
    a = sampler.sample(500, np.random.default_rng(42))
    b = sampler.sample(500, np.random.default_rng(42))
    c = sampler.sample(500, np.random.default_rng(43))
    np.testing.assert_array_equal(a.goals, b.goals)
    np.testing.assert_array_equal(a.q, b.q)
    assert a.proposals == b.proposals
    assert not np.array_equal(a.goals, c.goals)
    # A fresh sampler (its probe runs again) draws the same goals from the same seed.
    d = cls(regions.get("farbox"), 3, CONSTRAINED_START).sample(500, np.random.default_rng(42))
    np.testing.assert_array_equal(a.goals, d.goals)


def test_single_goals_for_env_resets() -> None:
    sampler = JointSpaceSampler(regions.get("farbox"), 3, CONSTRAINED_START)
    rng = np.random.default_rng(0)
    goals = np.array([sampler.sample(1, rng).goals[0] for _ in range(50)])
    assert regions.get("farbox").contains(goals).all()
    assert len(np.unique(goals, axis=0)) == 50
    assert sampler.sample(0, rng).goals.shape == (0, 3)


def test_joint_space_acceptance_matches_a_direct_count() -> None:
    # Acceptance two ways: the sampler's proposal count, and a plain Monte Carlo count.
    region = regions.get("closebox")
    batch = JointSpaceSampler(region, 3, CONSTRAINED_START).sample(
        3000, np.random.default_rng(3))
    q = np.tile(np.asarray(CONSTRAINED_START), (200_000, 1))
    q[:, :3] = np.random.default_rng(4).uniform(-np.pi, np.pi, (200_000, 3))
    goals = ur5kin.fk(q) + np.array([0.0, 0.0, H])
    direct = np.mean(region.contains(goals) & ur5kin.plane_clear(q, H))
    sigma = np.sqrt(direct * (1 - direct) / 3000) * 4
    assert batch.acceptance == pytest.approx(direct, abs=sigma)


def test_cartesian_goals_are_uniform_in_a_reachable_box() -> None:
    # A box well inside the reach: every point is reachable, so the goals are uniform in it.
    box = regions.parse("box:0.3,0.5,-0.3,0.3,0.3,0.5")
    batch = CartesianSampler(box, 3, CONSTRAINED_START).sample(4000, np.random.default_rng(5))
    assert batch.reachable_fraction > 0.99
    np.testing.assert_allclose(batch.goals.mean(axis=0), [0.4, 0.0, 0.4], atol=0.01)
    np.testing.assert_allclose(batch.goals.std(axis=0), [0.2 / 12**0.5, 0.6 / 12**0.5,
                                                         0.2 / 12**0.5], rtol=0.05)


@pytest.mark.parametrize("cls", [JointSpaceSampler, CartesianSampler])
def test_unreachable_region_fails_at_construction(cls) -> None:
    # How fast it fails is measured by python -m benchmarks.goal_sampling, not asserted here.
    with pytest.raises(UnreachableRegionError, match=r"no goals reachable|outside the box"):
        cls(regions.parse("box:-0.2,0.2,-0.2,0.2,5,6"), 3, CONSTRAINED_START)


def test_region_out_of_reach_of_few_joints_fails_at_construction() -> None:
    # With 2 joints and the constrained start, tool0 stays on a surface; a small box off it
    # holds no goal. The error says so and names the region, the joints and the start pose.
    with pytest.raises(UnreachableRegionError) as info:
        JointSpaceSampler(regions.parse("box:-0.1,0.1,-0.1,0.1,0.9,1.0"), 2, CONSTRAINED_START)
    message = str(info.value)
    assert "box:-0.1,0.1,-0.1,0.1,0.9,1.0" in message and "2 joints" in message
    assert "0 of" in message


def test_cartesian_sampler_needs_three_joints() -> None:
    with pytest.raises(ValueError, match="surface"):
        CartesianSampler(regions.get("farbox"), 2, CONSTRAINED_START)


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"n_joints": 7}, "n_joints"),
    ({"n_joints": 2.5}, "n_joints"),
    ({"start_q": (0.0,) * 5}, "start_q"),
    ({"base_height": -1.0}, "base_height"),
    ({"region": "farbox"}, "regions.Region"),
])
def test_bad_sampler_arguments_are_named(kwargs: dict, match: str) -> None:
    args = {"region": regions.get("farbox"), "n_joints": 3, "start_q": CONSTRAINED_START}
    with pytest.raises(ValueError, match=match):
        JointSpaceSampler(**{**args, **kwargs})


def test_sample_checks_its_arguments() -> None:
    sampler = JointSpaceSampler(regions.get("farbox"), 3, CONSTRAINED_START)
    with pytest.raises(ValueError, match="Generator"):
        sampler.sample(3, 0)
    with pytest.raises(ValueError, match=r"n=-?\w* \(expected an integer >= 0"):
        sampler.sample(-1, np.random.default_rng())


@pytest.mark.parametrize("cls", [JointSpaceSampler, CartesianSampler])
def test_samplers_round_trip_through_json(cls) -> None:
    sampler = cls(regions.get("zheight"), 4, CONSTRAINED_START)
    back = sampler_from_dict(json.loads(json.dumps(sampler.to_dict())))
    assert type(back) is cls and back.to_dict() == sampler.to_dict()
    np.testing.assert_array_equal(sampler.sample(50, np.random.default_rng(0)).goals,
                                  back.sample(50, np.random.default_rng(0)).goals)


def test_base_height_moves_the_goals() -> None:
    low = JointSpaceSampler(regions.get("unconstrained", 0.1), 3, UNCONSTRAINED_START, 0.1)
    high = JointSpaceSampler(regions.get("unconstrained", 0.5), 3, UNCONSTRAINED_START, 0.5)
    a = low.sample(200, np.random.default_rng(0))
    b = high.sample(200, np.random.default_rng(0))
    np.testing.assert_allclose(ur5kin.fk(b.q)[:, 2] + 0.5, b.goals[:, 2], atol=1e-12)
    assert b.goals[:, 2].mean() > a.goals[:, 2].mean()

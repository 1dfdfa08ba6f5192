"""The task specification: defaults from docs/design.md, JSON round trips, errors at construction,
and the physics checks that construction leaves to :func:`envs.checks.validate`."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import regions
from envs.checks import validate
from envs.gains import joint_inertia_bounds
from envs.physics.pinocchio_loop import PinocchioDynamics
from envs.reach import UR5ReachEnv
from envs.spec import DEFAULT_KD, DEFAULT_KP, TaskSpec


def test_defaults_are_the_papers_task():
    task = TaskSpec()
    assert task.region == "unconstrained"
    assert task.start_q == (0.0,) * 6  # the paper's unconstrained start
    assert (task.success_radius, task.max_episode_steps, task.control_hz) == (0.1, 100, 50)
    assert (task.distance_weight, task.action_weight, task.success_reward) == (1.0, 1.0, 100.0)
    assert task.dt == 0.02 and task.substeps == 20 and task.sim_dt == 0.001
    assert task.base_height == 0.1 and task.control_mode == "position"


@pytest.mark.parametrize("region", ["zheight", "closebox", "farbox", "farbox_tall",
                                    "box:0.3,0.8,-0.3,0.3,0,0.5"])
def test_constrained_regions_start_at_the_resolved_constrained_pose(region):
    task = TaskSpec(region=region, n_joints=3)
    assert task.start_q == pytest.approx((0.0, -math.pi / 4, math.pi / 2, 0.0, 0.0, 0.0))
    assert task.to_dict()["start_q"] == list(task.start_q)  # the record holds the resolved pose


def test_explicit_start_is_kept_and_a_default_start_follows_the_region():
    task = TaskSpec(region="farbox")
    assert task.replace(region="unconstrained").start_q == (0.0,) * 6
    chosen = TaskSpec(region="farbox", start_q=(0.1, -0.5, 1.0, 0.0, 0.0, 0.0))
    assert chosen.replace(region="zheight").start_q == (0.1, -0.5, 1.0, 0.0, 0.0, 0.0)


def test_region_objects_and_dicts_become_strings_that_rebuild_them():
    farbox = regions.get("farbox")
    assert TaskSpec(region=farbox).region == "farbox"  # equal to a registered one: its name
    custom = regions.Box.from_limits((0.2, 0.6, -0.2, 0.2, 0.0, 0.3), "mine")
    task = TaskSpec(region=custom)
    assert task.goal_region == custom
    assert TaskSpec(region=custom.to_dict()) == task
    assert TaskSpec.from_json(task.to_json()).goal_region == custom


def test_json_round_trip_and_hash():
    task = TaskSpec(region="zheight", n_joints=5, control_mode="velocity", reward_type="sparse",
                    kp=tuple(2 * k for k in DEFAULT_KP), plane_margin=0.01)
    text = task.to_json()
    assert json.loads(text)["kp"] == [2 * k for k in DEFAULT_KP]
    back = TaskSpec.from_json(text)
    assert back == task and hash(back) == hash(task)
    assert {task: 1}[back] == 1


@settings(max_examples=25, deadline=None)
@given(n_joints=st.integers(2, 6), radius=st.floats(1e-3, 1.0),
       weight=st.floats(0.0, 10.0), steps=st.integers(1, 500),
       mode=st.sampled_from(["position", "velocity", "torque"]),
       region=st.sampled_from(list(regions.names())))
def test_any_valid_task_round_trips_through_json(n_joints, radius, weight, steps, mode, region):
    task = TaskSpec(region=region, n_joints=n_joints, success_radius=radius,
                    action_weight=weight, max_episode_steps=steps, control_mode=mode)
    assert TaskSpec.from_json(task.to_json()) == task


def test_default_gains_are_the_documented_design():
    # kp = I_max w^2, kd = 2 zeta I_max w at w = 30 rad/s, zeta = 1, rounded to 3 significant digits
    high, w, zeta = joint_inertia_bounds()[1], 30.0, 1.0
    kp, kd = high * w**2, 2.0 * zeta * high * w
    np.testing.assert_allclose(DEFAULT_KP, kp, rtol=2e-3)
    np.testing.assert_allclose(DEFAULT_KD, kd, rtol=2e-3)


BAD_FIELDS = [
    ({"n_joints": 1}, "n_joints"),
    ({"n_joints": 7}, "n_joints"),
    ({"n_joints": 2.5}, "n_joints"),
    ({"n_joints": True}, "n_joints"),
    ({"control_mode": "pos"}, "control_mode"),
    ({"reward_type": "shaped"}, "reward_type"),
    ({"goal_sampler": "uniform"}, "goal_sampler"),
    ({"goal_sampler": "cartesian", "n_joints": 2}, "needs n_joints >= 3"),
    ({"success_radius": 0.0}, "success_radius"),
    ({"success_radius": -0.1}, "success_radius"),
    ({"success_radius": float("nan")}, "success_radius"),
    ({"max_episode_steps": 0}, "max_episode_steps"),
    ({"control_hz": -50}, "control_hz"),
    ({"control_hz": 50.0}, "control_hz"),
    ({"sim_hz": 1001}, "multiple of control_hz"),
    ({"sim_hz": 0}, "sim_hz"),
    ({"base_height": -0.1}, "base_height"),
    ({"action_weight": -1.0}, "action_weight"),
    ({"plane_margin": float("inf")}, "plane_margin"),
    ({"terminate_on_success": 1}, "terminate_on_success"),
    ({"kp": (1.0,) * 5}, "kp"),
    ({"kp": (-1.0, *DEFAULT_KP[1:])}, "kp"),
    ({"kd": (0.0,) * 6}, "kd"),
    ({"region": "nowhere"}, "nowhere"),
    ({"region": 3}, "region"),
    ({"start_q": (0.0, 0.0)}, "start_q"),
]

UNRUNNABLE = [
    ({"start_q": (0.0, math.pi / 2, 0.0, 0.0, 0.0, 0.0)}, "plane"),  # the arm points down
    ({"start_q": (0.0, -1.0, 7.0, 0.0, 0.0, 0.0)}, "start_q[2]"),  # elbow beyond 2 pi
    ({"kd": tuple(100 * k for k in DEFAULT_KD)}, "unstable"),
    ({"sim_hz": 100, "control_hz": 50}, "unstable"),
]
"""Tasks that are well-formed records but that the robot cannot run."""


@pytest.mark.parametrize(("fields", "message"), BAD_FIELDS)
def test_invalid_values_raise_at_construction_naming_the_field(fields, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        TaskSpec(**fields)


@pytest.mark.parametrize(("fields", "message"), UNRUNNABLE)
def test_unrunnable_tasks_are_records_that_validate_and_the_dynamics_refuse(fields, message):
    task = TaskSpec(**fields)  # a record: reading it checks no physics
    assert TaskSpec.from_json(task.to_json()) == task
    for check in (validate, PinocchioDynamics, lambda t: UR5ReachEnv(task=t)):
        with pytest.raises(ValueError, match=re.escape(message)):
            check(task)


def test_runnable_tasks_pass_validate_unchanged():
    for region in regions.names():
        task = TaskSpec(region=region)
        assert validate(task) is task


def test_reading_a_task_loads_neither_pinocchio_nor_torch_nor_the_inertias():
    # a fresh interpreter: this one has loaded everything already
    code = (
        "import sys\n"
        "from envs.spec import TaskSpec\n"
        "for region in ('unconstrained', 'zheight', 'closebox', 'farbox', 'farbox_tall'):\n"
        "    task = TaskSpec(region=region, n_joints=4, goal_sampler='cartesian')\n"
        "    assert TaskSpec.from_json(task.to_json()) == task\n"
        "import envs.gains\n"
        "print(sorted(m for m in ('pinocchio', 'torch') if m in sys.modules),\n"
        "      envs.gains.joint_inertia_bounds.cache_info().currsize)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.split() == ["[]", "0"]


def test_unknown_fields_are_named_with_the_valid_ones():
    with pytest.raises(ValueError, match=r"unknown task field\(s\) \['n_joint'\]"):
        TaskSpec.from_dict({"n_joint": 3})
    with pytest.raises(ValueError, match="fields are"):
        TaskSpec().replace(colour="red")
    with pytest.raises(ValueError, match="not valid JSON"):
        TaskSpec.from_json("{")


def test_the_spec_is_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        TaskSpec().n_joints = 4  # type: ignore[misc]

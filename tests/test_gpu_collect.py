"""benchmarks.gpu_collect: what a GPU grid brings back is the runs' records, and policies that
load as the whole run folder does."""

import io
import tarfile

import numpy as np
import pytest
from toy_goal_env import ENV_ID

import ddpg_her
from benchmarks import gpu_collect
from ddpg_her.config import AgentConfig
from ddpg_her.trainer import Trainer

pytestmark = pytest.mark.xdist_group("test_gpu_collect")
"""Under pytest-xdist one worker runs this module, so that the toy grid (`grid`) is trained once."""

TINY = AgentConfig(episodes=3, eval_every=3, eval_episodes=2, hidden_sizes=(8, 8),
                   updates_per_episode=2, buffer_size=100, batch_size=8, warmup_episodes=1)


@pytest.fixture(scope="module")
def grid(tmp_path_factory):
    """Two settings of the toy env (2 and 3 joints), two seeds each, under root/."""
    root = tmp_path_factory.mktemp("grid")
    for joints in (2, 3):
        t = Trainer(ENV_ID, {"region": "box", "n_joints": joints}, TINY, [0, 1],
                    [str(root / f"box-j{joints}" / f"s{s}") for s in (0, 1)], progress=False,
                    tensorboard=False)
        try:
            t.run()
        finally:
            t.close()
    return root


def test_grid_records_and_slim_policies_that_load_as_the_run(grid, tmp_path):
    files = gpu_collect.pack(grid, tmp_path / "out", [("box", 2)], max_bytes=2**24)
    assert [f.name for f in files] == ["grid.tar.gz", "policies.tar.gz"]
    with tarfile.open(files[0]) as tar:
        names = set(tar.getnames())
    assert names == {f"box-j{j}/s{s}/{n}" for j in (2, 3) for s in (0, 1)
                     for n in ("spec.json", "eval.csv")}
    with tarfile.open(files[1]) as tar:
        tar.extractall(tmp_path / "back", filter="data")
        assert not [n for n in tar.getnames() if "j3" in n]
    for s in (0, 1):
        whole = ddpg_her.load(grid / "box-j2" / f"s{s}")
        dims = whole.spec["dims"]
        rng = np.random.default_rng(s)
        obs = {"observation": rng.normal(size=dims["obs_dim"]),
               "achieved_goal": rng.normal(size=dims["goal_dim"]),
               "desired_goal": rng.normal(size=dims["goal_dim"])}
        slim = ddpg_her.load(tmp_path / "back" / "box-j2" / f"s{s}")
        assert slim.episode == whole.episode == 3
        np.testing.assert_array_equal(slim(obs), whole(obs))
        ckpt = next((tmp_path / "back" / "box-j2" / f"s{s}" / "checkpoints").iterdir())
        assert ckpt.stat().st_size < next(
            (grid / "box-j2" / f"s{s}" / "checkpoints").iterdir()).stat().st_size


def test_large_files_are_split_and_too_many_refused(grid, tmp_path):
    whole = gpu_collect.pack(grid, tmp_path / "a", [("box", 2)], max_bytes=2**24)
    limit = max(f.stat().st_size for f in whole) // 2 + 1
    files = gpu_collect.pack(grid, tmp_path / "b", [("box", 2)], max_bytes=limit)
    assert all(f.stat().st_size <= limit for f in files) and len(files) > 2
    for original in whole:
        pieces = sorted(f for f in files if f.name.startswith(original.name))
        assert len(pieces) == 1 or pieces[0].name == original.name + ".part00"
        with tarfile.open(fileobj=io.BytesIO(b"".join(p.read_bytes() for p in pieces))) as tar, \
                tarfile.open(original) as want:
            assert tar.getnames() == want.getnames()
    with pytest.raises(ValueError, match="more than 8"):
        gpu_collect.pack(grid, tmp_path / "c", [("box", 2)], max_bytes=200)
    with pytest.raises(ValueError, match="more than 1"):
        gpu_collect.pack(grid, tmp_path / "e", [("box", 2)], max_bytes=2**24, max_files=1)
    with pytest.raises(ValueError, match="no run folder"):
        gpu_collect.pack(tmp_path / "c", tmp_path / "d", [], max_bytes=200)


def test_the_grid_time_of_each_part_comes_back(grid, tmp_path):
    for part in (2, 3):
        (grid / f"grid_time-part{part}.json").write_text('{"wall_s": 1}')
    try:
        files = gpu_collect.pack(grid, tmp_path / "out", [], max_bytes=2**24)
    finally:
        for part in (2, 3):
            (grid / f"grid_time-part{part}.json").unlink()
    assert [f.name for f in files] == ["grid.tar.gz"]
    with tarfile.open(files[0]) as tar:
        names = set(tar.getnames())
    assert {"grid_time-part2.json", "grid_time-part3.json"} <= names

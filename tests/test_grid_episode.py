"""benchmarks.grid_episode: the JSON it prints, its counters against calls made on purpose, and
the grid's settings against the paper's."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import torch

from analysis.paper import PAPER_GRID
from benchmarks import grid_episode

TINY = "--hidden-sizes 8 8 --buffer-size 1000 --batch-size 8 --updates-per-episode 2 " \
       "--task max_episode_steps=5"
"""Units small enough for the CPU in seconds (the path and its counts stay today's)."""


def test_the_cpu_path_prints_the_figures_as_json():
    run = subprocess.run(
        [sys.executable, "-m", "benchmarks.grid_episode", "--device", "cpu", "--json",
         "--path", "today", "--part", "2", "--seeds", "2", "--episodes", "2", "--warmup", "2",
         f"--unit-args={TINY}"], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    result = json.loads(run.stdout)
    assert {"device", "ms_per_grid_episode", "startup_s", "host_syncs_per_episode",
            "graph_replays_per_episode"} <= set(result)
    assert result["agents"] == 2 and result["path"] == "today"
    assert len(result["episode_ms"]) == 2
    assert result["ms_per_grid_episode"] > 0 and result["startup_s"] > 0
    for key in ("host_syncs_per_episode", "graph_replays_per_episode"):
        assert isinstance(result[key], int) and result[key] >= 0, key
    # today's loop reads losses and successes on the host every episode, and has no graph
    # on the CPU: the counter is wired to the episode it counts
    assert result["host_syncs_per_episode"] > 0
    assert result["graph_replays_per_episode"] == 0


@pytest.mark.parametrize("window", [True, False])
def test_the_program_path_times_its_session_and_save_apart(window):
    """The default path is the program: after the default warm-up, its timed episodes, then
    test sessions and their saves timed apart and amortised over 100 episodes; a window save
    writes eval.csv only, so it costs less than one writing chunks and checkpoints."""
    run = subprocess.run(
        [sys.executable, "-m", "benchmarks.grid_episode", "--device", "cpu", "--json",
         "--part", "2", "--seeds", "1", "--episodes", "1", "--sessions", "2",
         *(["--window"] if window else []), f"--unit-args={TINY}"],
        capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    result = json.loads(run.stdout)
    assert result["path"] == "program" and result["window"] is window
    assert result["warmup"] == grid_episode.DEFAULT_WARMUP
    assert result["test_session_ms"] > 0 and result["save_ms"] > 0
    assert result["ms_per_grid_episode_with_session_and_save"] == pytest.approx(
        result["ms_per_grid_episode"]
        + (result["test_session_ms"] + result["save_ms"]) / 100)
    assert result["replayed_timed_episodes"] == 0  # nothing is captured on the CPU


def test_the_default_warm_up_ends_with_the_capture():
    """The program's acting and update bodies run eagerly WARMUP_REPLAYS times after the
    random-action episodes, then capture: the first timed episode is the one after that."""
    from ddpg_her.program import WARMUP_REPLAYS

    assert grid_episode.DEFAULT_WARMUP == grid_episode.RL_WARMUP_EPISODES + WARMUP_REPLAYS + 1


def test_the_cpu_counter_counts_each_host_read():
    x = torch.ones(3)
    with grid_episode.counters("cpu") as counts:
        x.sum().item()
        x.tolist()
        x.numpy()
        x.cpu()
        if x[0]:
            pass
        x + 1  # no read
    assert counts.host_syncs == 5
    assert counts.replays == 0
    x.sum().item()  # the methods are restored
    assert counts.host_syncs == 5
    assert torch.Tensor.item is torch._C.TensorBase.item


def test_the_grid_and_its_parts_are_the_papers():
    assert len(grid_episode.grid_settings(None)) * 5 == 55
    assert grid_episode.grid_settings(None) == PAPER_GRID
    assert grid_episode.grid_settings(3) == (("unconstrained", 3), ("zheight", 3),
                                             ("closebox", 3), ("farbox", 3))
    assert sum(len(grid_episode.grid_settings(j)) for j in range(2, 7)) == len(PAPER_GRID)
    with pytest.raises(ValueError, match="--part must be a joint count of the paper grid"):
        grid_episode.grid_settings(7)


def test_bad_arguments_are_refused_by_name():
    run = subprocess.run([sys.executable, "-m", "benchmarks.grid_episode", "--device", "cpu",
                          "--part", "7"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "--part must be a joint count" in run.stderr
    run = subprocess.run([sys.executable, "-m", "benchmarks.grid_episode", "--device", "cpu",
                          "--episodes", "0"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "--episodes" in run.stderr


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_the_cuda_counters_see_one_sync_and_one_replay():
    x = torch.ones(64, device="cuda")
    y = torch.empty_like(x)
    graph = torch.cuda.CUDAGraph()
    side = torch.cuda.Stream()
    side.wait_stream(torch.cuda.current_stream())
    with torch.cuda.stream(side):
        y.copy_(x * 2)
    torch.cuda.current_stream().wait_stream(side)
    with torch.cuda.graph(graph):
        y.copy_(x * 2)
    with grid_episode.counters("cuda") as counts:
        graph.replay()
        y.sum().item()  # one synchronising read
        y.add_(1)  # none
    assert counts.replays == 1
    assert counts.host_syncs == 1


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_every_timed_episode_replays_on_cuda():
    """On CUDA, after the default warm-up, every timed episode of the program replays its
    captured acting and update bodies (none runs eagerly or captures)."""
    run = subprocess.run(
        [sys.executable, "-m", "benchmarks.grid_episode", "--device", "cuda", "--json",
         "--part", "2", "--seeds", "1", "--episodes", "2", "--sessions", "1", "--window",
         f"--unit-args={TINY}"], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    result = json.loads(run.stdout)
    assert result["replayed_timed_episodes"] == 2
    assert result["graph_replays_per_episode"] >= 2


class _Stub:
    """A grid runner that only counts its episodes (and reads one value per episode)."""

    def __init__(self):
        self.episodes = 0

    def episode(self):
        self.episodes += 1
        torch.ones(2).sum().item()

    def synchronize(self):
        pass

    def close(self):
        pass


def test_measure_warms_up_times_and_counts_apart(tmp_path, monkeypatch):
    import time

    runner = _Stub()
    figures = grid_episode.measure(runner, "cpu", episodes=3, warmup=2, count_episodes=2,
                                   t0=time.perf_counter())
    assert runner.episodes == 2 + 3 + 2
    assert len(figures["episode_ms"]) == 3
    assert figures["host_syncs_per_episode"] == 1  # the stub's one .item() per episode
    go = tmp_path / "go"
    monkeypatch.setattr(grid_episode, "START_AFTER_TIMEOUT_S", 0.5)
    with pytest.raises(TimeoutError, match="did not appear within"):
        grid_episode.measure(_Stub(), "cpu", 1, 1, 1, time.perf_counter(), start_after=go)
    go.touch()
    figures = grid_episode.measure(_Stub(), "cpu", 1, 1, 1, time.perf_counter(),
                                   start_after=go)
    assert figures["waited_s"] < 0.5

"""benchmarks.agent_updates: the machine peak (its FLOP count, its rate on the CPU, and with a GPU
that it measures the device the update runs on), and the rollout timing of the two host env
backends, and the graph-against-eager update timing."""

import pytest
import torch
from torch.utils.flop_counter import FlopCounterMode

from benchmarks import agent_updates as bench


@pytest.mark.parametrize("n", [3, 64, 200])
def test_the_peaks_flop_count_is_torchs_count_of_the_product(n):
    a, b = torch.randn(n, n), torch.randn(n, n)
    with FlopCounterMode(display=False) as counter:
        torch.mm(a, b)
    assert bench.matmul_flops(n) == counter.get_total_flops()


def test_the_cpu_peak_is_a_sane_rate_that_a_larger_problem_does_not_move_wildly():
    small = bench.matmul_peak_gflops("cpu", sizes=(256,), repeats=3)
    large = bench.matmul_peak_gflops("cpu", sizes=(512,), repeats=3)
    # one loaded core of a 2-core CI machine does ~10-50 GFLOP/s; no CPU core does 10 TFLOP/s
    assert 0.1 < small < 1e4 and 0.1 < large < 1e4
    assert 0.1 < large / small < 10


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_the_cuda_peak_is_the_gpus_and_bounds_the_updates_rate():
    """The bug this guards: the peak was measured on the CPU while the update ran on the GPU,
    which gave an H100 a 1.2 TFLOP/s peak and a peak fraction of 2.2."""
    cpu = bench.matmul_peak_gflops("cpu", sizes=(1024,), repeats=2)
    cuda = bench.matmul_peak_gflops("cuda")
    assert cuda > 5 * cpu


def test_rollout_timing_runs_both_backends_and_refuses_a_negative_count(capsys):
    result = bench.measure_rollouts(3, 3, rounds=1)
    assert result["rollout_agents"] == 3
    assert result["rollout_numpy_s"] > 0 and result["rollout_batched_s"] > 0
    assert result["rollout_speedup"] == pytest.approx(
        result["rollout_numpy_s"] / result["rollout_batched_s"])  # one round: its own ratio
    with pytest.raises(SystemExit):
        bench.main(["--rollout", "-1"])
    assert "--rollout must be >= 0, got 0, -1" in capsys.readouterr().err

"""Where the second core goes: the update's biggest matrix product at 1 and 2 threads.

Times ``torch.bmm`` of (K, 64, 400) by (K, 400, 300), the shape of the second layer of the
actor (the critic's is 403 rows), for K = 1..10 agents at 1 and 2 torch threads in alternating
rounds, and two independent K = 5 products run at once on two Python threads of 1 torch thread
each. Prints one JSON object; times in microseconds, medians of the rounds.

    python results/throughput/gemm_scaling.py
"""

import json
import statistics
import threading
import time

import torch

KS = (1, 2, 4, 5, 6, 8, 10)
REPEATS, ROUNDS = 20, 15


def timed(fn) -> float:
    t = time.perf_counter()
    for _ in range(REPEATS):
        fn()
    return (time.perf_counter() - t) / REPEATS * 1e6


def main() -> None:
    torch.manual_seed(0)
    data = {k: (torch.randn(k, 64, 400), torch.randn(k, 400, 300), torch.empty(k, 64, 300))
            for k in KS}
    pair = [data[5], tuple(t.clone() for t in data[5])]
    times: dict[str, list[float]] = {}

    def bmm(x, w, out):
        return lambda: torch.bmm(x, w, out=out)

    def on_thread(i):
        torch.set_num_threads(1)
        bmm(*pair[i])()

    def two_at_once():
        threads = [threading.Thread(target=lambda i=i: [on_thread(i) for _ in range(REPEATS)])
                   for i in range(2)]
        t = time.perf_counter()
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        return (time.perf_counter() - t) / (2 * REPEATS) * 1e6  # per product

    for _ in range(ROUNDS):
        for threads in (1, 2):
            torch.set_num_threads(threads)
            for k in KS:
                times.setdefault(f"T{threads}_K{k}", []).append(timed(bmm(*data[k])))
        torch.set_num_threads(1)
        times.setdefault("T1_alone_K5", []).append(timed(bmm(*pair[0])))
        times.setdefault("two_threads_K5", []).append(two_at_once())
    med = {key: statistics.median(v) for key, v in times.items()}
    result = {
        "us_per_product": {k: {"threads_1": round(med[f"T1_K{k}"]),
                               "threads_2": round(med[f"T2_K{k}"]),
                               "scaling": round(med[f"T1_K{k}"] / med[f"T2_K{k}"], 2)}
                           for k in KS},
        "k5_one_thread_alone_us": round(med["T1_alone_K5"]),
        "k5_two_at_once_us_per_product": round(med["two_threads_K5"]),
        "cpu_threads": torch.get_num_threads(), "torch": torch.__version__,
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()

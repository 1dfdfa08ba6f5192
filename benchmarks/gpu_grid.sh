#!/usr/bin/env bash
# The paper's grid (55 runs x 20,000 episodes, issue 24) and its micro-benchmarks on a GPU
# machine lent for at most 30 minutes. Read benchmarks/GPU.md first; every step, in order:
#
#   here, once:         bash benchmarks/gpu_grid.sh prepare      # builds .devsite.tgz, checks sizes
#   there (device run, carry [".devsite.tgz"]), each a separate call:
#     bash benchmarks/gpu_grid.sh bench [updates|kernel|envs]  # tests on cuda + benchmarks -> $OUT
#     bash benchmarks/gpu_grid.sh start [SETTING ...]   # the grid, detached (setsid nohup)
#     bash benchmarks/gpu_grid.sh poll [SECONDS]        # waits up to SECONDS (<= 540), prints progress
#     bash benchmarks/gpu_grid.sh collect               # packs results into $OUT (<= 8 files)
#   here, to check it without a GPU:
#     bash benchmarks/gpu_grid.sh dry                   # every step on the cpu, tiny, in a temp dir
#
# SETTING is REGION:JOINTS (e.g. unconstrained:3); none means the whole paper grid. Variables:
# EPISODES (20000), DEVICE (cuda), RUNS (runs/paper_grid), ENV_BACKEND (batched), SEEDS (5),
# ENV_DYNAMICS (torch; numba with ENV_BACKEND=torch: the envs on the fused CUDA kernel).
set -euo pipefail
cd "$(dirname "$0")/.."

EPISODES=${EPISODES:-20000}
DEVICE=${DEVICE:-cuda}
RUNS=${RUNS:-runs/paper_grid}
ENV_BACKEND=${ENV_BACKEND:-batched}
ENV_DYNAMICS=${ENV_DYNAMICS:-torch}
SEEDS=${SEEDS:-5}
OUT=${OUT:-$RUNS/out}
PY=${PY:-python3}
MAX_CARRY_MIB=64

# The Pinocchio bundle of ../shared/tools/device-site.sh, unpacked as its header says.
site() {
    if [[ -f .devsite.tgz && ":${PYTHONPATH:-}:" != *":/tmp/devsite:"* ]]; then
        tar xzf .devsite.tgz -C /tmp
        export PYTHONPATH=/tmp/devsite:/tmp/devsite/cmeel.prefix/lib/python3.12/site-packages:$PWD
    fi
    export PYTHONUNBUFFERED=1
}

# grid_command [SETTING ...] [-- TRAIN_ARGS ...]: the sweep's command line
grid_command() {
    local sel=() rest=()
    while [[ $# -gt 0 && $1 != -- ]]; do sel+=(--setting "$1"); shift; done
    [[ $# -gt 0 ]] && { shift; rest=(-- "$@"); }
    [[ ${#sel[@]} -gt 0 ]] || sel=(--grid paper)
    local dynamics=""
    [[ $ENV_DYNAMICS == torch ]] || dynamics="--env-dynamics $ENV_DYNAMICS"
    echo "$PY -m analysis.sweep ${sel[*]} --one-process --device $DEVICE" \
         "--env-backend $ENV_BACKEND $dynamics --seeds $SEEDS --episodes $EPISODES" \
         "--out $RUNS ${rest[*]}"
}

prepare() {
    [[ -f .devsite.tgz ]] || bash ../shared/tools/device-site.sh
    local tree carry
    tree=$(git ls-files -z --cached --others --exclude-standard -- . ':!.devsite.tgz' \
           | du -cb --files0-from=- 2>/dev/null \
           | tail -1 | cut -f1)
    carry=$(stat -c %s .devsite.tgz)
    echo "working tree $((tree / 1048576)) MiB + .devsite.tgz $((carry / 1048576)) MiB" \
         "(limit $MAX_CARRY_MIB MiB together)"
    if (( (tree + carry) / 1048576 >= MAX_CARRY_MIB )); then
        echo "too large to travel: ignore or move what the device does not need" >&2; exit 1
    fi
    echo 'device run: carry [".devsite.tgz"], command "bash benchmarks/gpu_grid.sh bench" (then start, poll, collect)'
}

# bench [updates|kernel|envs]: updates and kernel by default; on a cold machine the two together
# come near a call's 10 minutes, so run them as two calls where time matters; envs only when named
bench() {
    site
    mkdir -p "$OUT"
    local part=${1:-all}
    case $part in all|updates|kernel|envs) ;; *) echo "bench: updates, kernel, envs or nothing; got $part" >&2; exit 2 ;; esac
    $PY -c "import torch; print(torch.__version__, torch.cuda.get_device_name())" | tee "$OUT/device.txt"
    [[ $part == all || $part == updates ]] && bench_updates
    [[ $part == all || $part == kernel ]] && bench_kernel
    [[ $part == envs ]] && bench_envs
    return 0
}

bench_updates() {
    # the capturable step on this device, and the ensemble's replay of device rows: their tests
    # (the cuda ones run here only)
    $PY -m pytest -q -p no:cacheprovider tests/test_update_graph.py tests/test_ensemble.py \
        -k "graph or capturable or cuda or tensor_rows" 2>&1 | tail -5 | tee "$OUT/tests.txt"
    # issue 24: stacked updates of 55 agents, graph against eager (goal >= 100k agent-updates/s),
    # and of 5, the size of one setting's stack
    $PY -m benchmarks.agent_updates --device "$DEVICE" --graph 55 --only-graph --updates 100 \
        --rounds 10 --fill-episodes 3 --json | tee "$OUT/graph55.json"
    $PY -m benchmarks.agent_updates --device "$DEVICE" --graph 5 --only-graph --updates 100 \
        --rounds 10 --fill-episodes 3 --json | tee "$OUT/graph5.json"
}

bench_kernel() {
    # issue 24: the fused dynamics kernel (envs/physics/numba_cuda.py), untested on a GPU until
    # this runs: its tests against the CPU kernel on this GPU (and the float32 PTX check), then
    # a control step of 55 copies (goal <= 50 us) and copy-steps/s at N = 4096 (goal >= 5 M)
    # and 65536, against the torch backend's CUDA graph on the same GPU
    # (a failure is reported, and the benchmark runs all the same)
    $PY -m pytest -q -p no:cacheprovider tests/test_numba_cuda.py \
        -k "not simulator and not dry_run" 2>&1 | tail -15 | tee "$OUT/tests_kernel.txt" \
        || echo "the kernel's tests FAILED on this GPU: see tests_kernel.txt"
    # the kernel behind TorchReach's tensors (ENV_DYNAMICS=numba): rollouts against the torch
    # kernel, zero copy, no sync in step, launches ordered on a side stream, a tiny training
    $PY -m pytest -q -p no:cacheprovider tests/test_torchreach_numba.py -k "gpu" 2>&1 \
        | tail -15 | tee "$OUT/tests_torchreach_numba.txt" \
        || echo "TorchReach on the kernel FAILED on this GPU: see tests_torchreach_numba.txt"
    $PY -m benchmarks.cuda_dynamics --device "$DEVICE" --sizes 55 4096 65536 --torch graph \
        --threads-per-block 32 64 128 --rounds 3 --json | tee "$OUT/cuda_dynamics.json"
}

bench_envs() {
    # issue 24: the torch env backend's merged twins (one TorchReach per set of agents equal but
    # for their goals) against one twin per agent: seconds per training episode and test
    # session of the 3-joint stack (4 settings x 5 seeds, 100 copies per agent in a test),
    # full episodes on the fused kernel; 10-step episodes on the torch kernel (~6,000
    # launches per twin and step: unmerged, 20 twins, it is slow)
    $PY -m benchmarks.torch_envs --device "$DEVICE" --env-dynamics numba --steps 100 \
        --eval-episodes 100 --rounds 3 | tee "$OUT/torch_envs_numba.json"
    $PY -m benchmarks.torch_envs --device "$DEVICE" --env-dynamics torch --steps 10 \
        --eval-episodes 100 --rounds 2 | tee "$OUT/torch_envs_torch.json"
}

start() {
    site
    mkdir -p "$RUNS"
    if [[ -f $RUNS/grid.pid ]] && kill -0 "$(cat "$RUNS/grid.pid")" 2>/dev/null; then
        echo "the grid already runs (pid $(cat "$RUNS/grid.pid"))"; return
    fi
    local cmd; cmd=$(grid_command "$@")
    echo "$cmd" >"$RUNS/grid.cmd"
    date +%s >"$RUNS/grid.start"
    # its own session: it outlives this call (the device tool ends a call's other processes)
    # shellcheck disable=SC2086
    setsid nohup bash -c "$cmd; echo \$? >'$RUNS/grid.rc'; date +%s >'$RUNS/grid.end'" \
        >"$RUNS/grid.log" 2>&1 < /dev/null &
    echo $! >"$RUNS/grid.pid"
    echo "started pid $(cat "$RUNS/grid.pid"): $cmd"
}

progress() {
    local rows=0 runs=0 f
    for f in $(find "$RUNS" -name eval.csv 2>/dev/null); do
        runs=$((runs + 1)); rows=$((rows + $(wc -l <"$f") - 1))
    done
    echo "$(date +%T) runs $runs, test sessions $rows, elapsed $(( $(date +%s) - $(cat "$RUNS/grid.start") )) s"
    tail -n 3 "$RUNS/grid.log" 2>/dev/null || true
}

poll() {
    local limit=${1:-540} waited=0
    (( limit <= 540 )) || limit=540  # a device call may last 600 s
    while (( waited < limit )) && [[ ! -f $RUNS/grid.rc ]]; do
        sleep 30; waited=$((waited + 30)); progress
    done
    if [[ -f $RUNS/grid.rc ]]; then echo "finished, status $(cat "$RUNS/grid.rc")"; fi
}

collect() {
    site
    mkdir -p "$OUT"
    if [[ -f $RUNS/grid.end ]]; then
        local wall=$(( $(cat "$RUNS/grid.end") - $(cat "$RUNS/grid.start") ))
        $PY - "$RUNS" "$wall" <<'EOF'
import json, sys, torch
root, wall = sys.argv[1], int(sys.argv[2])
device = torch.cuda.get_device_name() if torch.cuda.is_available() else "cpu"
command = open(f"{root}/grid.cmd").read().strip()
json.dump({"wall_s": wall, "device": device, "command": command},
          open(f"{root}/grid_time.json", "w"), indent=1)
EOF
    fi
    mkdir -p "$RUNS/logs"; cp "$RUNS"/grid.* "$RUNS/logs/" 2>/dev/null || true
    $PY -m benchmarks.gpu_collect "$RUNS" "$OUT"
}

dry() {
    local tmp; tmp=$(mktemp -d)
    trap 'rm -rf "$tmp"' RETURN
    export DEVICE=cpu EPISODES=2 SEEDS=1 RUNS=$tmp/runs OUT=$tmp/out
    bash -n "$0"
    echo "grid command: $(grid_command unconstrained:3 farbox:3)"
    start unconstrained:3 farbox:3 -- --eval-every 1 --eval-episodes 2 --updates-per-episode 2 \
        --warmup-episodes 1 --hidden-sizes 8 8 --buffer-size 1000
    poll 240
    collect
    ls -la "$OUT"
    tar tzf "$OUT/grid.tar.gz"
    tar tzf "$OUT/policies.tar.gz"
    # the kernel benchmark of `bench`, tiny, on the cpu (the kernel in numba's simulator)
    $PY -m benchmarks.cuda_dynamics --dry-run
    # the sweep resolves --update-graph auto (off on the cpu): run the captured step's flag too
    $PY -m ddpg_her.train --region unconstrained --joints 3 --seeds 0 1 --episodes 2 \
        --eval-every 1 --eval-episodes 2 --updates-per-episode 2 --warmup-episodes 1 \
        --hidden-sizes 8 8 --buffer-size 1000 --no-progress --no-tensorboard \
        --update-graph on --out "$tmp/graph/s{seed}"
    grep -h '"update_graph"' "$tmp"/graph/s*/spec.json
    # ENV_BACKEND=torch ENV_DYNAMICS=numba's training, on the cpu: the kernel in the simulator
    echo "with ENV_BACKEND=torch ENV_DYNAMICS=numba: $(ENV_BACKEND=torch ENV_DYNAMICS=numba \
        grid_command unconstrained:3)"
    NUMBA_ENABLE_CUDASIM=1 $PY -m ddpg_her.train --region unconstrained --joints 3 --seeds 0 \
        --episodes 1 --eval-every 1 --eval-episodes 1 --updates-per-episode 2 \
        --warmup-episodes 1 --hidden-sizes 8 8 --buffer-size 1000 --task max_episode_steps=5 \
        --no-progress --no-tensorboard --env-backend torch --env-dynamics numba \
        --out "$tmp/fused/s{seed}"
    grep -h '"env_dynamics"' "$tmp"/fused/s*/spec.json
    # bench envs, tiny: merged twins against one per agent, the kernel in the simulator
    NUMBA_ENABLE_CUDASIM=1 $PY -m benchmarks.torch_envs --settings zheight farbox --seeds 1 \
        --steps 2 --eval-episodes 1 --rounds 1 --env-dynamics numba
}

case "${1:-}" in
    prepare|bench|start|poll|collect|dry) cmd=$1; shift; "$cmd" "$@" ;;
    *) sed -n '2,15p' "$0"; exit 2 ;;
esac

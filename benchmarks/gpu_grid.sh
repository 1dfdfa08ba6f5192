#!/usr/bin/env bash
# A GPU window of 15 minutes in all (issue 35): one command, three stages. Read benchmarks/GPU.md.
#
# CARRY: [".devsite.tgz"]   (41 MB: Pinocchio, the UR5 model, gymnasium, trimesh, SB3 and the
#        numpy-2.5 shim of numba-cuda; built here once by `bash benchmarks/gpu_grid.sh prepare`)
# THE RUN TOOL'S COMMAND (timeout_s 600, carry as above), first call of a window:
#        bash benchmarks/gpu_grid.sh window 3
# and, if the window has device time left after it (status: budget_left_s > 240):
#        bash benchmarks/gpu_grid.sh finish 180
#
#   stage 1, smoke    <= 3 min: import checks, the device tests (pytest -m gpu)   -> $OUT/smoke.txt
#   stage 2, figures  <= 3 min: python -m benchmarks.gpu_figures              -> $OUT/figures.json
#   stage 3, grid     the rest: the training program on part J (joint count; 'all': the whole
#                     grid), started with setsid nohup, polled until the call's 10 minutes near
#                     their end, packed (<= 6 files: grid.tar.gz, policies.tar.gz, split at 15 MiB)
#                     Until `python -m analysis.sweep --help` lists --program it says so and runs
#                     nothing.
# Every file comes back in $OUT directly, 8 at most. Subcommands:
#   prepare                 here, once: build .devsite.tgz and check that it travels (<= 64 MiB)
#   window [J]              there: stages 1, 2, 3 in one call (<= 570 s)
#   smoke | figures | grid [J] | poll [SECONDS] | collect | finish [SECONDS]   one stage or step
#   dry                     here: all three stages on the CPU, tiny, in a temporary folder
# Variables: PY (python3), OUT (the run tool's $OUT; else runs/paper_grid/out), RUNS
# (runs/paper_grid), EPISODES (20000), DEVICE (cuda).
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PY:-python3}
DEVICE=${DEVICE:-cuda}
EPISODES=${EPISODES:-20000}
RUNS=${RUNS:-runs/paper_grid}
OUT=${OUT:-$RUNS/out}
DRY=${DRY:-0}
SMOKE_S=${SMOKE_S:-180}      # stage 1's budget, seconds
FIGURES_S=${FIGURES_S:-180}  # stage 2's budget, seconds
CALL_S=${CALL_S:-570}  # one call of the run tool lasts at most 600 s; this much is used
COLLECT_S=30     # kept for packing at the call's end
COLLECT_FILES=6  # what stage 3 may bring back: 8 less smoke.txt and figures.json
MAX_CARRY_MIB=64

# The Pinocchio bundle of ../shared/tools/device-site.sh, unpacked as its header says; its
# sitecustomize.py sets np.row_stack (numba-cuda 0.30.4 needs it, numpy 2.5 removed it).
# Not in the dry run: its wheels are for the GPU image's Python 3.12 and would shadow this one's.
site() {
    if [[ $DRY != 1 && -f .devsite.tgz && ":${PYTHONPATH:-}:" != *":/tmp/devsite:"* ]]; then
        tar xzf .devsite.tgz -C /tmp
        export PYTHONPATH=/tmp/devsite:/tmp/devsite/cmeel.prefix/lib/python3.12/site-packages:$PWD
    fi
    export PYTHONUNBUFFERED=1
    mkdir -p "$OUT"
}

stamp() { echo "[$(date -u +%T)] $*"; }

prepare() {
    # device-site.sh ends by adding the file to .git/info/exclude, which fails in a git
    # worktree (.git is a file there); .gitignore ignores it anyway, so only the archive counts
    [[ -f .devsite.tgz ]] || bash ../shared/tools/device-site.sh || true
    tar tzf .devsite.tgz >/dev/null || { echo "prepare: no readable .devsite.tgz" >&2; exit 1; }
    git check-ignore -q .devsite.tgz || { echo "prepare: .devsite.tgz is not ignored" >&2; exit 1; }
    local tree carry
    tree=$(git ls-files -z --cached --others --exclude-standard -- . ':!.devsite.tgz' \
           | du -cb --files0-from=- 2>/dev/null | tail -1 | cut -f1)
    carry=$(stat -c %s .devsite.tgz)
    echo "working tree $((tree / 1048576)) MiB + .devsite.tgz $((carry / 1048576)) MiB" \
         "(limit $MAX_CARRY_MIB MiB together)"
    if (( (tree + carry) / 1048576 >= MAX_CARRY_MIB )); then
        echo "too large to travel: ignore or move what the device does not need" >&2; exit 1
    fi
    echo 'run tool: command "bash benchmarks/gpu_grid.sh window 3", carry [".devsite.tgz"], timeout_s 600'
}

# ------------------------------------------------------------------ stage 1: smoke, <= 3 min
smoke() {
    site
    local deadline=$((SECONDS + SMOKE_S))
    {
        stamp "stage 1: smoke (budget ${SMOKE_S} s)"
        $PY - <<'EOF' || true
import importlib, time
import numpy as np
print("numpy", np.__version__, "| np.row_stack present:", hasattr(np, "row_stack"))
try:
    import torch
    print("torch", torch.__version__, "cuda", torch.version.cuda, "|",
          torch.cuda.get_device_name() if torch.cuda.is_available() else "no CUDA device")
except Exception as err:
    print(f"FAIL torch: {type(err).__name__}: {err}")
for name in ("numba.cuda", "triton", "pinocchio", "gymnasium", "trimesh"):
    tic = time.perf_counter()
    try:
        module = importlib.import_module(name)
        print(f"ok   {name} {getattr(module, '__version__', '')} "
              f"({time.perf_counter() - tic:.1f} s)")
    except Exception as err:
        print(f"FAIL {name}: {type(err).__name__}: {err}")
try:
    from numba import cuda
    print("numba sees a GPU:", cuda.is_available())
except Exception:
    pass
try:  # the bundle's UR5: example-robot-data's URDF through Pinocchio
    import pinocchio
    from ur5kin.model import urdf_path
    print(f"ok   UR5 model: {pinocchio.buildModelFromUrdf(str(urdf_path())).nq} joints "
          f"({urdf_path()})")
except Exception as err:
    print(f"FAIL UR5 model: {type(err).__name__}: {err}")
EOF
        # the device tests: every test marked gpu (skipped without a GPU); first those that
        # decide the kernel's route and have never run on a GPU (the program's captured bodies
        # against eager, the Triton stack kernel, the numba kernel, the grid episode's
        # counters), then the rest; -v: each test's line as it ends, so a cut at the budget
        # still says how far it got
        local first=(tests/test_program.py tests/test_stack_dynamics.py tests/test_numba_cuda.py
                     tests/test_counter_sampler.py tests/test_grid_episode.py)
        local files=() f
        for f in "${first[@]}" $(grep -l "mark.gpu" tests/test_*.py); do
            [[ -f $f && " ${files[*]} " != *" $f "* ]] && files+=("$f")
        done
        stamp "device tests: ${files[*]}"
        local left=$((deadline - SECONDS - 5))
        (( left > 10 )) || left=10  # timeout 0 would mean none
        timeout --kill-after=5 "$left" $PY -m pytest -p no:cacheprovider \
            -v -m gpu --continue-on-collection-errors "${files[@]}" 2>&1 | tail -n 80 \
            || stamp "device tests FAILED or cut at the budget (exit ${PIPESTATUS[0]})"
        stamp "stage 1 done"
    } 2>&1 | tee "$OUT/smoke.txt"
}

# ------------------------------------------------------------------ stage 2: figures, <= 3 min
figures() {
    site
    stamp "stage 2: figures (budget ${FIGURES_S} s) -> $OUT/figures.json"
    local dry=()
    [[ $DRY == 1 ]] && dry=(--dry-run)
    timeout --kill-after=5 "$FIGURES_S" $PY -m benchmarks.gpu_figures --out "$OUT/figures.json" \
        --budget-s $((FIGURES_S - 15)) "${dry[@]}" \
        || stamp "figures cut or failed (exit $?): $OUT/figures.json holds what was done"
    stamp "stage 2 done"
}

# ------------------------------------------------------------------ stage 3: the grid
# grid_command J: the training program's command for part J ('all': the whole grid)
grid_command() {
    local part=${1:-3} sel=()
    [[ $part == all ]] || sel=(--part "$part")
    if [[ $DRY == 1 ]]; then
        echo "$PY -m analysis.sweep --grid paper --program ${sel[*]} --episodes 2 --device cpu" \
             "--seeds 1 --out $RUNS -- --eval-every 1 --eval-episodes 2 --updates-per-episode 2" \
             "--warmup-episodes 1 --hidden-sizes 8 8 --buffer-size 1000"
    else
        echo "$PY -m analysis.sweep --grid paper --program ${sel[*]} --episodes $EPISODES" \
             "--device $DEVICE --out $RUNS"
    fi
}

# the same stages' machinery on today's sweep, tiny, for the dry run before --program exists
stand_in_command() {
    echo "$PY -m analysis.sweep --setting unconstrained:3 --one-process --device cpu --seeds 1" \
         "--episodes 2 --out $RUNS -- --eval-every 1 --eval-episodes 2" \
         "--updates-per-episode 2 --warmup-episodes 1 --hidden-sizes 8 8 --buffer-size 1000"
}

has_program() { $PY -m analysis.sweep --help 2>/dev/null | grep -q -- '--program'; }

grid() {
    site
    local part=${1:-3}
    [[ $part =~ ^([2-6]|all)$ ]] || { echo "grid: part J is a joint count 2-6 or 'all'; got $part" >&2; exit 2; }
    mkdir -p "$RUNS"
    if [[ -f $RUNS/grid.pid ]] && kill -0 "$(cat "$RUNS/grid.pid")" 2>/dev/null; then
        stamp "stage 3: the grid already runs (pid $(cat "$RUNS/grid.pid"))"; return
    fi
    local cmd
    if has_program; then
        cmd=$(grid_command "$part")
    elif [[ $DRY == 1 ]]; then
        cmd=$(stand_in_command)
        stamp "stage 3 (dry): analysis.sweep has no --program yet; today's sweep stands in"
    else
        stamp "stage 3: 'python -m analysis.sweep --help' lists no --program yet (issue 35's" \
              "training program): nothing started"
        return 0
    fi
    echo "$cmd" >"$RUNS/grid.cmd"
    echo "$part" >"$RUNS/grid.part"
    date +%s >"$RUNS/grid.start"
    rm -f "$RUNS/grid.rc" "$RUNS/grid.end"
    # its own session: it outlives this call (the run tool ends a call's other processes)
    setsid nohup bash -c "$cmd; echo \$? >'$RUNS/grid.rc'; date +%s >'$RUNS/grid.end'" \
        >"$RUNS/grid.log" 2>&1 </dev/null &
    echo $! >"$RUNS/grid.pid"
    stamp "stage 3: started pid $(cat "$RUNS/grid.pid"): $cmd"
}

progress() {
    local rows=0 runs=0 f
    while IFS= read -r f; do
        runs=$((runs + 1)); rows=$((rows + $(wc -l <"$f") - 1))
    done < <(find "$RUNS" -name eval.csv 2>/dev/null)
    stamp "runs $runs, test sessions $rows, elapsed $(( $(date +%s) - $(cat "$RUNS/grid.start") )) s"
    tail -n 2 "$RUNS/grid.log" 2>/dev/null || true
}

poll() {
    local limit=${1:-540} waited=0
    (( limit <= 540 )) || limit=540  # a call lasts at most 600 s
    [[ -f $RUNS/grid.start ]] || { stamp "poll: no grid started"; return 0; }
    while (( waited < limit )) && [[ ! -f $RUNS/grid.rc ]]; do
        local step=$(( limit - waited < 30 ? limit - waited : 30 ))
        sleep "$step"; waited=$((waited + step)); progress
    done
    if [[ -f $RUNS/grid.rc ]]; then stamp "the grid finished, status $(cat "$RUNS/grid.rc")"; fi
}

collect() {
    site
    [[ -f $RUNS/grid.start ]] || { stamp "collect: no grid started, nothing to pack"; return 0; }
    local part; part=$(cat "$RUNS/grid.part")
    local end; end=$(cat "$RUNS/grid.end" 2>/dev/null || date +%s)
    $PY - "$RUNS" "$part" $(( end - $(cat "$RUNS/grid.start") )) <<'EOF'
import json, os, sys, time
import torch
root, part, wall = sys.argv[1], sys.argv[2], int(sys.argv[3])
rc = open(f"{root}/grid.rc").read().strip() if os.path.exists(f"{root}/grid.rc") else None
json.dump({"part": part, "wall_s": wall, "finished": rc is not None, "exit_status": rc,
           "device": torch.cuda.get_device_name() if torch.cuda.is_available() else "cpu",
           "command": open(f"{root}/grid.cmd").read().strip(),
           "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())},
          open(f"{root}/grid_time-part{part}.json", "w"), indent=1)
EOF
    mkdir -p "$RUNS/logs"; cp "$RUNS"/grid.{cmd,log,part,start} "$RUNS/logs/" 2>/dev/null || true
    $PY -m benchmarks.gpu_collect "$RUNS" "$OUT" --max-files "$COLLECT_FILES" \
        || stamp "collect: nothing packed (no finished test session yet?)"
}

finish() { poll "${1:-180}"; collect; }

window() {
    local start=$SECONDS
    stamp "window: stages 1-3, part ${1:-3}, OUT=$OUT"
    smoke
    figures
    grid "${1:-3}"
    local left=$(( CALL_S - (SECONDS - start) - COLLECT_S ))
    (( left > 0 )) && poll "$left"
    collect
    ls -la "$OUT"
    stamp "window: $((SECONDS - start)) s in this call"
}

dry() {
    DRY_TMP=$(mktemp -d)
    trap 'rm -rf "$DRY_TMP"' EXIT
    export DRY=1 DEVICE=cpu EPISODES=2 RUNS=$DRY_TMP/runs OUT=$DRY_TMP/out PY
    bash -n "$0"
    stamp "dry run: every stage on the CPU, tiny, in $DRY_TMP"
    echo "the grid's command on a GPU: $(DRY=0 DEVICE=cuda EPISODES=20000 RUNS=runs/paper_grid grid_command 3)"
    CALL_S=420 window 2
    tar tzf "$OUT/grid.tar.gz"
    [[ ! -f $OUT/policies.tar.gz ]] || tar tzf "$OUT/policies.tar.gz"
    local n; n=$(find "$OUT" -maxdepth 1 -type f | wc -l)
    (( n <= 8 )) || { echo "dry: $n files in OUT, more than 8" >&2; exit 1; }
    stamp "dry run done: $n files would come back"
}

case "${1:-}" in
    prepare|window|smoke|figures|grid|poll|collect|finish|dry) cmd=$1; shift; "$cmd" "$@" ;;
    *) sed -n '2,24p' "$0"; exit 2 ;;
esac

#!/usr/bin/env bash
# A GPU window of 15 minutes in all (issues 35, 42): the grid's training first, the rest beside
# it. Read benchmarks/GPU.md.
#
# CARRY: [".devsite.tgz"]   (41 MB: Pinocchio, the UR5 model, gymnasium, trimesh, SB3; built
#        here once by `bash benchmarks/gpu_grid.sh prepare`)
# THE RUN TOOL'S CALLS (timeout_s 600, carry as above), back to back:
#        bash benchmarks/gpu_grid.sh window          (first call: <= 570 s)
#        bash benchmarks/gpu_grid.sh finish 240      (second call: until the grid ends, packed)
#
#   grid     first, detached (setsid nohup): the training program on part J ('all', the whole
#            grid, by default) in window mode (--window: eval.csv every session, policies at the
#            end, no buffers or mid-run checkpoints: it cannot be resumed) with --budget-seconds
#            TRAIN_S: after its second test session it measures its ms per episode and trains
#            the largest of 20000/10000/5000/2500 episodes projected to end within TRAIN_S of
#            its start, re-deciding at each session (logs/one-process.log says which)
#   smoke    beside it, <= 110 s: imports, the device tests (pytest -m gpu)   -> $OUT/smoke.txt
#   figures  beside it, <= 110 s, at the same time as smoke (both within 2 minutes):
#            python -m benchmarks.gpu_figures, the program's grid episode first  -> figures.json
#   poll, collect: until the call's end, then packed (<= 6 files: grid.tar.gz, policies.tar.gz)
# Every file comes back in $OUT directly, 8 at most. Subcommands:
#   prepare                 here, once: build .devsite.tgz and check that it travels (<= 64 MiB)
#   window [J]              there: grid, smoke and figures beside it, poll, collect (<= 570 s)
#   grid [J] | smoke | figures | poll [SECONDS] | collect | finish [SECONDS]   one step
#   dry                     here: the window on the CPU, tiny, in a temporary folder
# Variables: PY (python3), OUT (the run tool's $OUT; else runs/paper_grid/out), RUNS
# (runs/paper_grid), EPISODES (20000), TRAIN_S (720), DEVICE (cuda).
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PY:-python3}
DEVICE=${DEVICE:-cuda}
EPISODES=${EPISODES:-20000}
TRAIN_S=${TRAIN_S:-720}      # the training process's budget, seconds from its start
RUNS=${RUNS:-runs/paper_grid}
OUT=${OUT:-$RUNS/out}
DRY=${DRY:-0}
BESIDE_S=${BESIDE_S:-110}    # smoke and figures, at the same time, beside the grid
CALL_S=${CALL_S:-570}  # one call of the run tool lasts at most 600 s; this much is used
COLLECT_S=30     # kept for packing at the call's end
COLLECT_FILES=6  # what the grid may bring back: 8 less smoke.txt and figures.json
MAX_CARRY_MIB=64

# The Pinocchio bundle of ../shared/tools/device-site.sh, unpacked as its header says. Not in
# the dry run: its wheels are for the GPU image's Python 3.12 and would shadow this one's.
site() {
    if [[ $DRY != 1 && -f .devsite.tgz && ":${PYTHONPATH:-}:" != *":/tmp/devsite:"* ]]; then
        [[ -d /tmp/devsite ]] || tar xzf .devsite.tgz -C /tmp
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
    echo 'run tool: command "bash benchmarks/gpu_grid.sh window", carry [".devsite.tgz"], timeout_s 600'
}

# ------------------------------------------------------------------ the grid, first
# grid_command J: the training program's command for part J ('all': the whole grid)
grid_command() {
    local part=${1:-all} sel=()
    [[ $part == all ]] || sel=(--part "$part")
    if [[ $DRY == 1 ]]; then
        echo "$PY -m analysis.sweep --grid paper --program --window --budget-seconds $TRAIN_S" \
             "${sel[*]} --episodes 4 --device cpu --seeds 1 --out $RUNS -- --eval-every 1" \
             "--eval-episodes 2 --updates-per-episode 2 --warmup-episodes 1 --hidden-sizes 8 8" \
             "--buffer-size 1000 --task max_episode_steps=10"
    else
        echo "$PY -m analysis.sweep --grid paper --program --window --budget-seconds $TRAIN_S" \
             "${sel[*]} --episodes $EPISODES --device $DEVICE --out $RUNS"
    fi
}

grid() {
    site
    local part=${1:-all}
    [[ $part =~ ^([2-6]|all)$ ]] || { echo "grid: part J is a joint count 2-6 or 'all'; got $part" >&2; exit 2; }
    mkdir -p "$RUNS"
    if [[ -f $RUNS/grid.pid ]] && kill -0 "$(cat "$RUNS/grid.pid")" 2>/dev/null; then
        stamp "grid: already runs (pid $(cat "$RUNS/grid.pid"))"; return
    fi
    local cmd; cmd=$(grid_command "$part")
    echo "$cmd" >"$RUNS/grid.cmd"
    echo "$part" >"$RUNS/grid.part"
    date +%s >"$RUNS/grid.start"
    rm -f "$RUNS/grid.rc" "$RUNS/grid.end"
    # its own session: it outlives this call (the run tool ends a call's other processes)
    setsid nohup bash -c "$cmd; echo \$? >'$RUNS/grid.rc'; date +%s >'$RUNS/grid.end'" \
        >"$RUNS/grid.log" 2>&1 </dev/null &
    echo $! >"$RUNS/grid.pid"
    stamp "grid: started pid $(cat "$RUNS/grid.pid"): $cmd"
}

# ------------------------------------------------------------------ smoke, beside the grid
smoke() {
    site
    {
        stamp "smoke (budget ${BESIDE_S} s, beside the grid)"
        $PY - <<'EOF' || true
import importlib, time
try:
    import torch
    print("torch", torch.__version__, "cuda", torch.version.cuda, "|",
          torch.cuda.get_device_name() if torch.cuda.is_available() else "no CUDA device")
except Exception as err:
    print(f"FAIL torch: {type(err).__name__}: {err}")
for name in ("numba", "triton", "pinocchio", "gymnasium", "trimesh"):
    tic = time.perf_counter()
    try:
        module = importlib.import_module(name)
        print(f"ok   {name} {getattr(module, '__version__', '')} "
              f"({time.perf_counter() - tic:.1f} s)")
    except Exception as err:
        print(f"FAIL {name}: {type(err).__name__}: {err}")
try:  # the bundle's UR5: example-robot-data's URDF through Pinocchio
    import pinocchio
    from ur5kin.model import urdf_path
    print(f"ok   UR5 model: {pinocchio.buildModelFromUrdf(str(urdf_path())).nq} joints "
          f"({urdf_path()})")
except Exception as err:
    print(f"FAIL UR5 model: {type(err).__name__}: {err}")
EOF
        # every test marked gpu (skipped without a GPU); first the program's captures
        # (deterministic mode included; the Triton kernel the grid compiles meanwhile, then
        # from Triton's disk cache) and the compiled Triton kernel (not the interpreter:
        # TRITON_INTERPRET=0) against the numba CPU kernel; -v: each test's line as it ends,
        # so a cut at the budget still says how far it got
        local first=(tests/test_program.py tests/test_stack_dynamics.py tests/test_grid_episode.py
                     tests/test_counter_sampler.py)
        local files=() f
        for f in "${first[@]}" $(grep -l "mark.gpu" tests/test_*.py); do
            [[ -f $f && " ${files[*]} " != *" $f "* ]] && files+=("$f")
        done
        stamp "device tests: ${files[*]}"
        TRITON_INTERPRET=0 timeout --kill-after=5 "$BESIDE_S" $PY -m pytest -p no:cacheprovider \
            -v -m gpu --continue-on-collection-errors "${files[@]}" 2>&1 | tail -n 80 \
            || stamp "device tests FAILED or cut at the budget (exit ${PIPESTATUS[0]})"
        stamp "smoke done"
    } >"$OUT/smoke.txt" 2>&1
}

# ------------------------------------------------------------------ figures, beside the grid
figures() {
    site
    local dry=()
    [[ $DRY == 1 ]] && dry=(--dry-run)
    {
        stamp "figures (budget ${BESIDE_S} s, beside the grid) -> $OUT/figures.json"
        timeout --kill-after=5 "$BESIDE_S" $PY -m benchmarks.gpu_figures \
            --out "$OUT/figures.json" --budget-s $((BESIDE_S - 10)) "${dry[@]}" \
            --note "measured beside the grid's training on the same device (gpu_grid.sh): times are upper bounds" \
            || stamp "figures cut or failed (exit $?): $OUT/figures.json holds what was done"
        stamp "figures done"
    } >"$OUT/figures.log" 2>&1
}

# smoke and figures at once, beside the grid: both within BESIDE_S
beside() {
    smoke & local smoke_pid=$!
    figures & local figures_pid=$!
    wait "$smoke_pid" || true
    wait "$figures_pid" || true
    cat "$OUT/figures.log" >>"$OUT/smoke.txt"; rm -f "$OUT/figures.log"
    cat "$OUT/smoke.txt"
}

# ------------------------------------------------------------------ poll and pack
progress() {
    local rows=0 runs=0 f
    while IFS= read -r f; do
        runs=$((runs + 1)); rows=$((rows + $(wc -l <"$f") - 1))
    done < <(find "$RUNS" -name eval.csv 2>/dev/null)
    stamp "runs $runs, test sessions $rows, elapsed $(( $(date +%s) - $(cat "$RUNS/grid.start") )) s"
    grep -h "window budget" "$RUNS"/logs/one-process.log 2>/dev/null | tail -n 1 || true
    tail -n 1 "$RUNS/grid.log" 2>/dev/null || true
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
log = f"{root}/logs/one-process.log"
budget = [line.strip() for line in open(log) if "window budget" in line] \
    if os.path.exists(log) else []
json.dump({"part": part, "wall_s": wall, "finished": rc is not None, "exit_status": rc,
           "budget_decisions": budget,
           "device": torch.cuda.get_device_name() if torch.cuda.is_available() else "cpu",
           "command": open(f"{root}/grid.cmd").read().strip(),
           "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())},
          open(f"{root}/grid_time-part{part}.json", "w"), indent=1)
EOF
    mkdir -p "$RUNS/logs"; cp "$RUNS"/grid.{cmd,log,part,start} "$RUNS/logs/" 2>/dev/null || true
    $PY -m benchmarks.gpu_collect "$RUNS" "$OUT" --max-files "$COLLECT_FILES" \
        || stamp "collect: nothing packed (no finished test session yet?)"
}

finish() { poll "${1:-240}"; collect; ls -la "$OUT"; }

window() {
    local start=$SECONDS
    stamp "window: the grid (part ${1:-all}) first, smoke and figures beside it, OUT=$OUT"
    grid "${1:-all}"
    beside
    local left=$(( CALL_S - (SECONDS - start) - COLLECT_S ))
    (( left > 0 )) && poll "$left"
    collect
    ls -la "$OUT"
    stamp "window: $((SECONDS - start)) s in this call"
}

dry() {
    DRY_TMP=$(mktemp -d)
    trap 'rm -rf "$DRY_TMP"' EXIT
    # the loaded CPU is slow: the figures' tiny run gets more time than a GPU's (300 s)
    export DRY=1 DEVICE=cpu RUNS=$DRY_TMP/runs OUT=$DRY_TMP/out PY TRAIN_S=600 \
        BESIDE_S=${DRY_BESIDE_S:-300}
    bash -n "$0"
    stamp "dry run: the window on the CPU, tiny, in $DRY_TMP"
    echo "the grid's command on a GPU: $(DRY=0 DEVICE=cuda EPISODES=20000 TRAIN_S=720 RUNS=runs/paper_grid grid_command all)"
    CALL_S=${DRY_CALL_S:-480} window 2
    [[ -f $RUNS/grid.rc ]] || { echo "dry: the grid did not finish within the call" >&2; exit 1; }
    grep -h "window budget" "$RUNS/logs/one-process.log" \
        || { echo "dry: the grid chose no budget" >&2; exit 1; }
    tar tzf "$OUT/grid.tar.gz"
    [[ ! -f $OUT/policies.tar.gz ]] || tar tzf "$OUT/policies.tar.gz"
    local n; n=$(find "$OUT" -maxdepth 1 -type f | wc -l)
    (( n <= 8 )) || { echo "dry: $n files in OUT, more than 8" >&2; exit 1; }
    stamp "dry run done: $n files would come back"
}

case "${1:-}" in
    prepare|window|smoke|figures|grid|poll|collect|finish|dry) cmd=$1; shift; "$cmd" "$@" ;;
    *) sed -n '2,27p' "$0"; exit 2 ;;
esac

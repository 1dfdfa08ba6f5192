#!/usr/bin/env bash
# The one set-up entry point: builds .venv from this project's own files, then runs a job.
#   bash dev.sh demo    the main job: a short training run, its learning curve and 3D replay
#   bash dev.sh test    the test suite (what .ci/run calls)
#   bash dev.sh shell   prints the activate line of the environment
# Environment: PYTHON (interpreter for the venv, default python3), VENV (default .venv),
# TORCH_INDEX_URL (an index serving PyTorch's CPU wheels, for machines whose default index
# only serves the CUDA build).
set -euo pipefail
cd "$(dirname "$0")"
venv=${VENV:-.venv}
python=${PYTHON:-python3}
stamp="$venv/.installed-$(cat pyproject.toml constraints.txt | sha1sum | cut -c1-12)"
if [ ! -f "$stamp" ]; then
  echo "dev.sh: setting up $venv (first run only, about two minutes)" >&2
  "$python" -m venv "$venv"
  torch_args=()
  if [ -n "${TORCH_INDEX_URL:-}" ]; then torch_args=(--index-url "$TORCH_INDEX_URL"); fi
  # torch first and pinned, so that nothing later can pull the CUDA build in as a dependency.
  "$venv/bin/python" -m pip install -q "${torch_args[@]}" "torch==2.13.0"
  "$venv/bin/python" -m pip install -q -c constraints.txt -e ".[test]"
  "$venv/bin/python" - <<'PY'
import torch, sys
if torch.version.cuda is not None:
    sys.exit(f"dev.sh: torch {torch.__version__} is a CUDA build; set TORCH_INDEX_URL to a CPU index")
PY
  rm -f "$venv"/.installed-*
  touch "$stamp"
fi
# The browser test of the 3D views (tests/test_view3d.py) needs headless Chromium. Install
# Debian's package where we can (root, apt-get, the package known); never fail the set-up for
# it: without it that one test skips and says why. DEV_NO_APT=1 skips the attempt.
browser_for_tests() {
  if command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 \
     || [ -n "${DEV_NO_APT:-}" ]; then return 0; fi
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "dev.sh: installing chromium for the browser test (apt-get, a few minutes)" >&2
    { apt-cache show chromium >/dev/null 2>&1 || apt-get update -qq; } >/dev/null 2>&1 || true
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null 2>&1 \
      || echo "dev.sh: could not install chromium; the browser test will skip" >&2
  else
    echo "dev.sh: no chromium; the browser test will skip (as root: apt-get install chromium)" >&2
  fi
}
job=${1:-}
shift || true
case "$job" in
  demo)
    # The main job: a short far-box training run (resumable), its learning curve and its
    # policy replayed in 3D (an offline HTML page). The curve is of runs/demo itself, so it
    # replaces the last one (--force) when the run goes on (--episodes 500).
    "$venv/bin/python" -m ddpg_her.train --region farbox --joints 3 --seed 0 --episodes 300 \
      --out runs/demo --resume "$@"
    "$venv/bin/python" -m analysis.curves runs/demo --out runs/demo/curves.png --force
    exec "$venv/bin/python" -m analysis.replay runs/demo --episodes 5 --no-progress \
      --out runs/demo/replay.html ;;
  test)
    browser_for_tests
    # One pytest worker per core (pytest-xdist; at most 8: each worker holds torch), tests
    # handed out one at a time except each xdist_group (a module whose module fixtures train or
    # simulate), which stays on one worker. Later arguments win: `bash dev.sh test -n 0` runs
    # in this one process.
    exec "$venv/bin/python" -m pytest -n auto --maxprocesses 8 --dist loadgroup "$@" ;;
  shell) echo "source $venv/bin/activate" ;;
  *) echo "usage: bash dev.sh demo|test|shell [args...]" >&2; exit 2 ;;
esac

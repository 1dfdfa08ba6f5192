"""Walk the README as a newcomer would: run every command of its quick start and of its command
table, in order, with a small budget, and record what each did.

    python -m benchmarks.readme_walk --clone /tmp/walk --out results/readme_walk/walk.csv

``--clone`` is a fresh clone of this repository (made with ``git clone`` if the folder does not
exist; its ``bash dev.sh`` set-up is part of the quick start and is timed). Budgets are cut so
that the walk takes minutes, not days: ``--episodes N`` of a training run becomes 20 episodes
with a test session of 5 goals every 10, the sweep runs its 2-joint part for 100 episodes and
one seed, sample counts shrink (the rules are ``SMALL`` below); the dry run and the projection
keep their own defaults, since their cost is what the walk measures. The test suite is not
walked (``bash dev.sh test`` is timed on its own). A command "works" when it exits 0; its wall
seconds, exit status and last output line go to the CSV, one row each.
"""

from __future__ import annotations

import argparse
import csv
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

SMALL = [  # (pattern, replacement) applied to each command line in turn
    (r"--episodes 1000\b", "--episodes 20 --eval-every 10 --eval-episodes 5"),
    (r"--episodes 300\b", "--episodes 20 --eval-every 10 --eval-episodes 5"),
    (r"(analysis\.sweep --grid paper) --episodes 3000 --workers 2$",
     r"\1 --part 2 --episodes 100 --seeds 1 --workers 2"),  # one setting, one test session
    (r"(analysis\.sb3 .*)$", r"\1 --episodes 20 --eval-every 10 --eval-episodes 5"),
    (r"--timesteps 20000", "--timesteps 400"),
    (r"--goals 2000", "--goals 200"),
    (r"--episodes 5 --out runs/replay", "--episodes 2 --out runs/replay"),
]
"""How each README command is made small (regular expressions, in order)."""


def readme_commands(readme: str) -> list[str]:
    """The commands of the README's quick start (its ``bash dev.sh demo`` line) and of its
    command table (each backticked ``python ...`` in the second column), in order."""
    found = ["bash dev.sh demo --episodes 20 --eval-every 10 --eval-episodes 5"]
    for line in readme.splitlines():
        if line.startswith("| ") and "`" in line:
            cells = line.split(" | ")
            if len(cells) >= 2:
                found += [c for c in re.findall(r"`([^`]+)`", cells[1])
                          if c.startswith(("python ", "bash ")) and len(c.split()) > 3
                          and not c.startswith("bash dev.sh test")]
    return found


def small(command: str) -> str:
    """``command`` with the budgets of ``SMALL``."""
    for pattern, replacement in SMALL:
        command = re.sub(pattern, replacement, command)
    return command


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clone", type=Path, required=True,
                        help="the fresh clone to walk in (cloned from this repository if absent)")
    parser.add_argument("--out", type=Path, required=True, help="the CSV of the walk (a row a "
                        "command: wall seconds, exit status, last line)")
    parser.add_argument("--timeout", type=float, default=1800.0,
                        help="wall seconds one command may take (s, > 0; default: 1800)")
    args = parser.parse_args(argv)
    if not args.timeout > 0:
        parser.error(f"--timeout {args.timeout}: expected seconds > 0")
    if not args.clone.exists():
        subprocess.run(["git", "clone", "-q", str(ROOT), str(args.clone)], check=True)
    commands = readme_commands((args.clone / "README.md").read_text())
    python = str((args.clone / ".venv" / "bin" / "python").resolve())
    rows = []
    for i, command in enumerate(commands):
        line = small(command)
        run = re.sub(r"^python ", shlex.quote(python) + " ", line)
        start = time.perf_counter()
        try:
            done = subprocess.run(run, shell=True, cwd=args.clone, capture_output=True,
                                  text=True, timeout=args.timeout)
            rc, output = done.returncode, (done.stdout + done.stderr).strip()
        except subprocess.TimeoutExpired:
            rc, output = "timeout", ""
        seconds = time.perf_counter() - start
        last = output.splitlines()[-1][-200:] if output else ""
        rows.append({"step": i, "command": line, "seconds": f"{seconds:.1f}", "rc": rc,
                     "last_line": last})
        print(f"[{i + 1}/{len(commands)}] rc={rc} {seconds:7.1f} s  {line}\n    {last}",
              flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    failed = [r for r in rows if r["rc"] != 0]
    print(f"{len(rows) - len(failed)} of {len(rows)} README commands worked -> {args.out}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

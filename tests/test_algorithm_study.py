"""The algorithm study's driver (analysis.algorithms): its units, commands and a real tiny run."""

from __future__ import annotations

import json
from pathlib import Path

from cli_tools import run_module

from analysis import algorithms


def test_dry_run_lists_every_algorithm_and_setting_with_its_command(tmp_path: Path) -> None:
    proc = run_module("analysis.algorithms", "--dry-run", "--out", str(tmp_path),
                      "--threads", "1")
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 4 * 4 * 5
    for name, algo in algorithms.ALGORITHMS.items():
        for region, joints in algorithms.SETTINGS:
            folder = tmp_path / name / f"{region}-j{joints}"
            mine = [ln for ln in lines if f" {folder}/s" in ln]
            assert [ln.split()[0] for ln in mine] == ["new"] * 5, (name, region)
            cmd = mine[0].split("<- python ")[1].split()
            at = cmd.index("--out")
            assert cmd[at - len(algo.args):at] == list(algo.args)
    assert "--exploration-rate 0 " in next(ln for ln in lines if "/sac/" in ln)
    assert "--algo ddpg --ensemble 4 " in next(ln for ln in lines if "/ensemble/" in ln)


def test_a_tiny_td3_and_sac_study_trains_and_records_its_algorithms(tmp_path: Path) -> None:
    toy = ["--env-id", "toy_goal_env:ToyReach-v0", "--hidden-sizes", "16", "16",
           "--eval-every", "2", "--eval-episodes", "2", "--updates-per-episode", "2",
           "--warmup-episodes", "1"]
    run_module("analysis.algorithms", "--out", str(tmp_path), "--seeds", "2", "--episodes", "4",
               "--setting", "box:2", "--algos", "td3", "sac", "--threads", "1", "--", *toy)
    for algo in ("td3", "sac"):
        for seed in (0, 1):
            run = tmp_path / algo / "box-j2" / f"s{seed}"
            assert json.loads((run / "spec.json").read_text())["agent"]["algo"] == algo
            assert len((run / "eval.csv").read_text().splitlines()) == 1 + 2  # sessions 2, 4
    assert json.loads((tmp_path / "sac" / "reading.json").read_text())["args"] == \
        ["--algo", "sac", "--exploration-rate", "0"]


def test_a_tiny_ensemble_study_trains_and_records_its_partition(tmp_path: Path) -> None:
    toy = ["--env-id", "toy_goal_env:ToyReach-v0", "--hidden-sizes", "16", "16",
           "--eval-every", "2", "--eval-episodes", "2", "--updates-per-episode", "4",
           "--warmup-episodes", "1"]
    run_module("analysis.algorithms", "--out", str(tmp_path), "--seeds", "1", "--episodes", "4",
               "--setting", "box:2", "--algos", "ensemble", "--threads", "1", "--", *toy)
    run = tmp_path / "ensemble" / "box-j2" / "s0"
    spec = json.loads((run / "spec.json").read_text())
    assert spec["agent"]["algo"] == "ddpg" and spec["agent"]["ensemble"] == 4
    assert spec["partition"]["method"] == "kmeans" and len(spec["partition"]["centres"]) == 4
    assert len((run / "eval.csv").read_text().splitlines()) == 1 + 2

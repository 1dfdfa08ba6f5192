"""analysis.claims: the sixteen claims' table, on fixtures (the unrun claims judged when their
runs are present, "not run" when absent) and on the committed results (the README's table is
the command's)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from analysis import claims
from analysis.paper import CLAIMS

ROOT = Path(__file__).resolve().parents[1]


def _runs(folder: Path, region: str, joints: int, levels: list[float], sessions: int = 10,
          task: dict | None = None) -> None:
    """5 seeds' run folders as ddpg_her.train writes them: seed i flat at ``levels[i]``."""
    for seed, level in enumerate(levels):
        run = folder / f"s{seed}"
        run.mkdir(parents=True)
        spec = {"format": "ddpg_her-run-1", "env_id": "UR5Reach-v0", "seed": seed,
                "env_kwargs": {"region": region, "n_joints": joints},
                "agent": {"episodes": 100 * sessions}, "task": task or {}}
        (run / "spec.json").write_text(json.dumps(spec))
        with open(run / "eval.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["episode", "successes", "tests", "mean_return",
                        "mean_final_distance_m", "env_steps", "wall_s"])
            for i in range(sessions):
                w.writerow([100 * (i + 1), level, 100, -1.0, 0.2, 100 * (i + 1) * 100, i])


def _rows(results: Path) -> dict[str, dict[str, str]]:
    return {r["claim"]: r for r in claims.table(results)}


def test_sixteen_claims_and_the_unrun_ones_say_not_run(tmp_path: Path) -> None:
    _runs(tmp_path / "sensitivity/runs/ours/farbox-j3", "farbox", 3, [100, 95, 98, 99, 97])
    rows = _rows(tmp_path)
    assert len(rows) == 16 == len(CLAIMS) + len(claims.EXTRA)
    for name, *_ in claims.EXTRA:
        assert rows[name]["verdict"] == "not run" and rows[name]["budget run"] == "-"
    assert rows[CLAIMS[0].name]["verdict"] == "holds"  # far box 3 by 1,000: every seed >= 90
    assert rows[CLAIMS[1].name]["verdict"] == "not run"  # no far box 6


def test_the_unrun_claims_are_judged_when_their_runs_land(tmp_path: Path) -> None:
    base = [100, 95, 98, 99, 97]
    _runs(tmp_path / "sensitivity/runs/ours/farbox-j3", "farbox", 3, base)
    _runs(tmp_path / "claims/velocity/runs", "farbox", 3, [2, 3, 4, 2, 3],
          task={"control_mode": "velocity"})
    _runs(tmp_path / "claims/torque/runs", "farbox", 3, [8, 12, 10, 9, 11])
    _runs(tmp_path / "claims/sparse/runs", "farbox", 3, [40, 50, 45, 55, 60])
    _runs(tmp_path / "claims/per/runs", "farbox", 3, [100, 96, 97, 99, 98])
    rows = _rows(tmp_path)
    # the 65 % Student-t interval over seeds, by scipy: torque's straddles 10, velocity's is
    # under it, so "only position control non-negligible" is within noise
    t = lambda v: stats.t.interval(0.65, 4, np.mean(v), stats.sem(v))  # noqa: E731
    assert t([2, 3, 4, 2, 3])[1] < 10 and t([8, 12, 10, 9, 11])[0] < 10 < t([8, 12, 10, 9, 11])[1]
    position = rows["only position control non-negligible"]
    assert position["verdict"] == "within noise" and position["budget run"] == "1,000"
    assert "velocity control 2.8" in position["our figure"]
    # each comparison's Welch p (scipy's) named in the figure: this claim has two
    welch = lambda v: stats.ttest_ind(base, v, equal_var=False).pvalue  # noqa: E731
    for name, levels in (("velocity", [2, 3, 4, 2, 3]), ("torque", [8, 12, 10, 9, 11])):
        assert f"{name} vs position: Welch p {welch(levels):.2g}" in position["our figure"]
    assert t([40, 50, 45, 55, 60])[1] < t(base)[0]
    assert rows["dense reward above sparse"]["verdict"] == "holds"
    assert t([100, 96, 97, 99, 98])[0] < t(base)[1]
    assert rows["prioritised replay destabilised learning"]["verdict"] == "within noise"
    # velocity alone under 10 by a clear margin and torque too: holds
    (tmp_path / "claims/torque").rename(tmp_path / "torque_old")
    _runs(tmp_path / "claims/torque/runs", "farbox", 3, [1, 0, 2, 1, 0])
    assert _rows(tmp_path)["only position control non-negligible"]["verdict"] == "holds"
    # a far box 1.0 m tall: an asymptote claim, not judgeable at 1,000 episodes
    _runs(tmp_path / "claims/farbox_tall/runs", "farbox_tall", 3, [99, 97, 98, 100, 96])
    tall = _rows(tmp_path)["far box 1.0 m tall like the far box"]
    assert tall["verdict"] == "not judgeable" and tall["budget needed"] == "20,000"


def test_a_shorter_variant_is_compared_at_its_own_budget_and_not_judged(tmp_path: Path
                                                                        ) -> None:
    """A variant run to 400 episodes is set beside far box 3's first 400 episodes, not its
    1,000 (a learning curve rises: unequal budgets would favour the longer run), and the
    claim is not judgeable until the variant reaches the claims' 1,000."""
    base = tmp_path / "sensitivity/runs/ours/farbox-j3"
    _runs(base, "farbox", 3, [100, 95, 98, 99, 97])
    for seed in range(5):  # the first four sessions low: 20 successes
        path = base / f"s{seed}" / "eval.csv"
        lines = path.read_text().splitlines()
        lines[1:5] = [",".join([line.split(",")[0], "20", *line.split(",")[2:]])
                      for line in lines[1:5]]
        path.write_text("\n".join(lines) + "\n")
    _runs(tmp_path / "claims/per/runs", "farbox", 3, [22, 18, 21, 19, 20], sessions=4)
    row = _rows(tmp_path)["prioritised replay destabilised learning"]
    assert row["verdict"] == "not judgeable" and row["budget run"] == "400"
    assert "far box 3 (position, dense, uniform) 20.0" in row["our figure"]
    assert "within noise so far" in row["our figure"]


def test_a_variant_of_another_setting_is_refused(tmp_path: Path) -> None:
    _runs(tmp_path / "claims/sparse/runs", "farbox", 6, [1, 2, 3, 4, 5])
    with pytest.raises(ValueError, match=r"claims/sparse/runs: expected far box 3 runs only"):
        claims.table(tmp_path)


def test_the_readme_table_is_the_commands(tmp_path: Path) -> None:
    """Every verdict the top-level README shows is the one the command computes today from
    the committed results (regenerate: python -m analysis.claims --readme README.md)."""
    readme = (ROOT / "README.md").read_text()
    shown = claims.readme_block(readme)
    rows = claims.table(ROOT / "results")
    assert shown == claims.block(rows)
    verdicts = {line.split(" | ")[0].lstrip("| "): line.split(" | ")[5]
                for line in shown.splitlines() if line.startswith("| ") and " | " in line}
    assert {r["claim"]: r["verdict"] for r in rows} == \
        {k: v for k, v in verdicts.items() if k != "claim"}
    # and the command writes it: a copy of the README with an emptied block gets it back
    copy = tmp_path / "README.md"
    copy.write_text(readme.replace(shown, "\n"))
    assert claims.main(["--results", str(ROOT / "results"), "--readme", str(copy),
                        "--out", str(tmp_path / "out")]) == 0
    assert copy.read_text() == readme
    with open(tmp_path / "out" / "claims.csv") as f:
        assert [r["verdict"] for r in csv.DictReader(f)] == [r["verdict"] for r in rows]


def test_a_readme_without_markers_is_one_clear_error(tmp_path: Path, capsys) -> None:
    bare = tmp_path / "README.md"
    bare.write_text("# no markers\n")
    with pytest.raises(SystemExit) as exc:
        claims.main(["--results", str(tmp_path), "--readme", str(bare)])
    assert exc.value.code == 1
    assert "has no <!-- claims:begin --> ... <!-- claims:end --> markers" in \
        capsys.readouterr().err


@pytest.mark.parametrize("out_holds", ["another table", "a file"])
def test_a_refused_out_leaves_the_readme_as_it_was(tmp_path: Path, capsys, out_holds) -> None:
    """--readme was written before --out was checked: an --out that held another table (or
    was a file) was refused with 'nothing was written', the README's block already replaced."""
    _runs(tmp_path / "results/sensitivity/runs/ours/farbox-j3", "farbox", 3, [100, 95, 98, 99])
    readme = tmp_path / "README.md"
    readme.write_text(f"# r\n{claims.BEGIN}\nan old table\n{claims.END}\n")
    out = tmp_path / "out"
    if out_holds == "a file":
        out.write_text("a file\n")
    else:
        (out / "claims.md").parent.mkdir()
        (out / "claims.md").write_text("another table\n")
    with pytest.raises(SystemExit) as exc:
        claims.main(["--results", str(tmp_path / "results"), "--readme", str(readme),
                     "--out", str(out)])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and str(out) in err and err.count("\n") == 1, err
    assert readme.read_text() == f"# r\n{claims.BEGIN}\nan old table\n{claims.END}\n"
    assert claims.main(["--results", str(tmp_path / "results"), "--readme", str(readme),
                        "--out", str(tmp_path / "new")]) == 0
    assert claims.readme_block(readme.read_text()) == claims.block(
        claims.table(tmp_path / "results"))

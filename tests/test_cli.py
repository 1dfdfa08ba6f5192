"""Every command line: each flag's help gives a unit or a range, and every example runs.

The command lines are found, not listed (see ``cli_tools``): a new ``python -m`` entry point is
checked without editing this file. Examples come from the README, ``docs/``, the modules'
docstrings, the parsers' descriptions and epilogs, and the "e.g. --flag VALUE" in flags' help.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
from pathlib import Path

import pytest
from cli_tools import (
    ROOT,
    cli_modules,
    example_scripts,
    load,
    options,
    parse_as_main,
    parser_of,
    split_command,
    takes_a_number,
)

CLIS = cli_modules() + example_scripts()

DEFAULT = re.compile(r"\(default: (?:%\(default\)s|[^)]*)\)|%\(default\)s")
"""argparse's default notes: they hold numbers and an "s" that would pass for a unit."""
UNIT = re.compile(
    r"(?<![\w^/'])(m|s|rad|rad/s|rad/s\^2|N m|Hz|m\^3|m/s)(?![\w/^])|%"
    r"|(?i:\b(count|fraction|probability|standard deviations|units|frames per second|episodes?|"
    r"steps?|transitions|updates|goals|configurations|agents|threads|copies|rounds|draws|"
    r"calls|samples|joints|processes|seeds?)\b)")
"""A physical unit, or the thing a count counts (an integer flag's unit is what it counts; a
seed is its own unit)."""
RANGE = re.compile(r"\d\s*\.\.\s*\w|\b\d+\s*-\s*\d+\b|[<>]=?\s*-?\d|\bin [\[(]")
"""A range: 2..6, 0..K-1, 2-6, >= 1, > 0, in [0, 1], in (0, 1]."""


def unit_or_range(text: str) -> bool:
    """Whether a flag's help states a unit or a range (argparse's default notes aside)."""
    text = DEFAULT.sub("", text)
    return bool(UNIT.search(text) or RANGE.search(text))


def test_the_unit_check_tells_units_from_none():
    for text in ("grid cell edge (m)", "controlled joints 2-6", "seed of the goals",
                 "torch CPU threads (count)", "Discount factor gamma, in [0, 1]",
                 "frames per second of the animation", "learning rate, > 0"):
        assert unit_or_range(text), text
    for text in ("grid cell edge", "Discount factor gamma (Table I). (default: %(default)s)",
                 "the agent's size (default: 3)", "learning rate of Adam"):
        assert not unit_or_range(text), text


@pytest.mark.parametrize("target", CLIS)
def test_every_flag_has_help_and_numbers_have_a_unit_or_range(target):
    parser = parser_of(target)
    assert parser.format_help()  # the help renders (a bare "%" in a help text would not)
    missing = [a.dest for a in options(parser) if not (a.help or "").strip()]
    assert not missing, f"{target}: flags without help: {missing}"
    unitless = [f"{'/'.join(a.option_strings) or a.dest}: {a.help!r}"
                for a in options(parser) if takes_a_number(a) and not unit_or_range(a.help)]
    assert not unitless, f"{target}: numeric flags whose help gives no unit or range:\n" + \
        "\n".join(unitless)


def test_the_command_lines_are_all_found():
    """The discovery finds the known entry points (so the parametrised tests are not empty)."""
    assert {"ddpg_her.train", "analysis.sweep", "analysis.region_volumes", "benchmarks.env_steps",
            "benchmarks.fk_paths", "benchmarks.goal_sampling", "benchmarks.agent_updates",
            "examples/animate_episode.py", "examples/ur5kin_tour.py"} <= set(CLIS)


# --- examples -------------------------------------------------------------------------------
PLACEHOLDER = re.compile(r"^(\[|<)|^[A-Z][A-Z_]*(\.\.\.)?$|^[A-Z_]+=")
"""A word standing for a value (K, RUN..., KEY=VALUE, [--flag N], <x>): not a runnable line."""


def _lines_of_markdown(text: str) -> list[str]:
    """Command lines of a Markdown text: lines of fenced blocks (backslash continuations
    joined) and inline code spans with arguments."""
    lines, fenced, held = [], False, ""
    for line in text.splitlines():
        if line.strip().startswith("```"):
            fenced = not fenced
            continue
        if fenced:
            held += line.rstrip()
            if held.endswith("\\"):
                held = held[:-1] + " "
                continue
            lines.append(held.strip())
            held = ""
        else:  # a span without arguments names a command rather than giving an example
            lines.extend(span for span in re.findall(r"`([^`]+)`", line)
                         if len(span.split()) > 3 or "examples/" in span)
    return lines


def _lines_of_cli(target: str) -> list[str]:
    """Command lines in a CLI's module docstring, its parser's description and epilog."""
    parser = parser_of(target)
    texts = [load(target).__doc__ or "", parser.description or "", parser.epilog or ""]
    return [line.strip() for text in texts for line in text.splitlines()]


def _help_fragments(target: str) -> list[list[str]]:
    """The "e.g. --flag VALUE" examples in a CLI's flags' help, as argv fragments."""
    found = []
    for action in options(parser_of(target)):
        for fragment in re.findall(r"e\.g\. (--[\w-]+ [^\s,;)]+)", action.help or ""):
            found.append(fragment.split())
    return found


def collect_examples() -> list[tuple[str, str, list[str]]]:
    """``(where, target, argv)`` of every runnable example command."""
    sources = [("README.md", line) for line in _lines_of_markdown((ROOT / "README.md")
                                                                  .read_text())]
    for page in sorted((ROOT / "docs").glob("*.md")):
        sources += [(f"docs/{page.name}", line) for line in _lines_of_markdown(page.read_text())]
    for target in CLIS:
        sources += [(target, line) for line in _lines_of_cli(target)]
    examples: dict[tuple[str, tuple[str, ...]], str] = {}  # the first place each is given
    first: dict[str, list[str]] = {}
    for where, line in sources:
        command = split_command(line) if line.startswith("python ") else None
        if command is None or any(PLACEHOLDER.search(word) for word in command[1]):
            continue
        examples.setdefault((command[0], tuple(command[1])), where)
        first.setdefault(command[0], command[1])
    for target in CLIS:
        for fragment in _help_fragments(target):
            assert target in first, f"{target}: an e.g. in its help but no full example to " \
                "extend; give one in its module docstring"
            examples.setdefault((target, (*first[target], *fragment)), f"{target} --help")
    return [(where, target, list(argv)) for (target, argv), where in examples.items()]


EXAMPLES = collect_examples()


class _StubMulti:
    """Stands in for ddpg_her.multi.MultiTrainer: builds each env as the trainer would, which
    checks every task field (the program: every agent's task as one stack, its own check),
    and trains nothing."""

    def __init__(self, settings, env_backend="numpy", **kwargs):
        import gymnasium

        from envs.stackreach import stack_tasks

        if env_backend == "program":
            stack_tasks([s.env_kwargs for s in settings for _ in s.seeds])
        for s in settings:
            gymnasium.make(s.env_id, **s.env_kwargs).close()
        self.groups, self.trainers, self.agents = [settings], [], 0

    def run(self):
        return [[[[] for _ in s.seeds] for s in group] for group in self.groups]

    def close(self):
        pass


def _run_train(argv: list[str], monkeypatch) -> None:
    """``python -m ddpg_her.train ARGV`` in this process, without training."""
    import torch

    from ddpg_her import train

    monkeypatch.setattr("ddpg_her.multi.MultiTrainer", _StubMulti)
    deterministic, threads = torch.are_deterministic_algorithms_enabled(), torch.get_num_threads()
    try:
        assert train.main(argv) == 0
    finally:
        torch.use_deterministic_algorithms(deterministic)
        torch.set_num_threads(threads)


def test_examples_are_found():
    targets = {target for _, target, _ in EXAMPLES}
    assert {"ddpg_her.train", "analysis.sweep", "analysis.success_map"} <= targets
    assert any(where.endswith("--help") for where, _, _ in EXAMPLES)  # the --task e.g.


@pytest.mark.parametrize(("where", "target", "argv"), EXAMPLES,
                         ids=[f"{w}: {t} {' '.join(a)}" for w, t, a in EXAMPLES])
def test_every_example_command_runs_or_at_least_parses(where, target, argv, tmp_path,
                                                       monkeypatch):
    """Training examples run up to the training itself (the task and agent fully checked);
    sweep dry runs run (up to a projection's training); the other examples (long studies
    over run folders) are parsed."""
    monkeypatch.chdir(tmp_path)
    stderr = io.StringIO()
    try:
        with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
            if target == "ddpg_her.train":
                _run_train(argv, monkeypatch)
            elif target == "analysis.sweep" and "--dry-run" in argv:
                # a --project trains two test intervals of every unit: reached, not run here
                monkeypatch.setattr("analysis.sweep.print_projection", lambda *a, **k: 0.0)
                assert load(target).main(argv) == 0
            else:
                parse_as_main(target, argv)
    except SystemExit as stop:
        error = stderr.getvalue().strip().splitlines()[-1:]
        pytest.fail(f"{where}: python {'-m ' if not target.endswith('.py') else ''}{target} "
                    f"{' '.join(argv)} exited with {stop.code}: {error}")
    assert not list(Path(tmp_path).rglob("*.pt")), "an example trained"


def test_a_broken_example_is_caught(monkeypatch, tmp_path):
    """The check above catches a task field that does not exist (the old --help example)."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit), contextlib.redirect_stderr(io.StringIO()):
        _run_train(["--region", "farbox", "--task", "reward=sparse"], monkeypatch)


def test_parser_of_leaves_argparse_as_it_was():
    parser_of("ddpg_her.summary")
    parser = argparse.ArgumentParser()
    parser.add_argument("--x", type=int)
    assert parser.parse_args(["--x", "3"]).x == 3


def test_train_help_lists_every_task_field_with_its_default():
    """``--task KEY=VALUE`` sets TaskSpec fields; --help names each with its default."""
    import dataclasses

    from envs.spec import TaskSpec

    text = " ".join(parser_of("ddpg_her.train").format_help().split())
    for f in dataclasses.fields(TaskSpec):
        assert f"{f.name}={f.default!r}".replace(" ", "") in text.replace(" ", ""), f.name


def test_a_training_process_and_a_study_default_to_one_torch_thread(monkeypatch):
    """Issue 37, kind 9: with torch's own choice (one thread per core) two trainers on 2 cores
    took 303 s each together against 41 s alone; one thread each, 48 s and 43 s. Without
    --threads, ``ddpg_her.train`` (and so ``dev.sh demo``) and every study run on
    DEFAULT_THREADS, whatever the cores and --workers."""
    import argparse

    import torch

    from analysis import sweep
    from ddpg_her import train
    from ddpg_her.units import DEFAULT_THREADS

    assert DEFAULT_THREADS == 1
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2)  # what torch chooses on a 2-core machine
        parser = train.make_parser()
        train.start_process(parser, train.parse_args(parser, ["--region", "farbox"]))
        assert torch.get_num_threads() == DEFAULT_THREADS
        train.start_process(parser, train.parse_args(parser, ["--region", "farbox",
                                                              "--threads", "2"]))
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(threads)
    monkeypatch.setattr("os.cpu_count", lambda: 16)
    study = argparse.ArgumentParser()
    sweep.add_execution_arguments(study, Path("runs"))
    assert sweep.check_execution_arguments(study, study.parse_args([])) == DEFAULT_THREADS
    assert sweep.check_execution_arguments(study, study.parse_args(["--threads", "3"])) == 3


@pytest.mark.parametrize("template", ["runs/{foo}", "runs/{0}", "runs/{seed"])
def test_an_out_template_with_a_field_train_does_not_fill_is_a_usage_error(template, capsys):
    """Issue 37, kind 4: ``--out runs/{foo}`` was a KeyError traceback from str.format."""
    from ddpg_her import train

    with pytest.raises(SystemExit) as exit_:
        train.main(["--region", "farbox", "--out", template])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert f"--out {template!r}: the only fields it may use are {{region}}" in err, err

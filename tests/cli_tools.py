"""Shared helpers of the command-line tests (not a test module): every CLI and its parser.

A command line is any module of the five packages that defines ``main`` behind
``if __name__ == "__main__":``, plus the scripts in ``examples/``. Their parsers are built inside
``main``, so :func:`parser_of` runs ``main`` with ``ArgumentParser.parse_args`` replaced by a
catch that hands the parser back before anything is parsed or run.
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import importlib
import importlib.util
import os
import shlex
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("ur5kin", "regions", "envs", "ddpg_her", "analysis")
TESTS = Path(__file__).resolve().parent


def child_env() -> dict[str, str]:
    """This process's environment for a subprocess: the tests (toy envs) and the project first
    on PYTHONPATH, whatever PYTHONPATH held kept after them (e.g. a GPU machine's carried
    packages, which a child that dropped them could not import)."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(TESTS), str(ROOT), os.environ.get("PYTHONPATH", "")])}


def run_module(*args: str, check: bool = True, timeout: float = 600,
               cwd: Path | None = None) -> subprocess.CompletedProcess:
    """``python -m ARGS`` in a subprocess with :func:`child_env`, output captured as text; the
    timeout (s) only guards against a hang."""
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True,
                          env=child_env(), timeout=timeout, check=check, cwd=cwd)


def package_modules(root: Path = ROOT) -> dict[str, Path]:
    """Every module of the five packages, ``{dotted name: file}`` (a package's ``__init__.py``
    under the package's name)."""
    modules = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            modules[".".join(parts)] = path
    return modules


def _is_script(path: Path) -> bool:
    """Whether the file defines ``main`` and calls it under ``if __name__ == "__main__":``."""
    tree = ast.parse(path.read_text())
    has_main = any(isinstance(n, ast.FunctionDef) and n.name == "main" for n in tree.body)
    guarded = any(isinstance(n, ast.If) and "__main__" in ast.unparse(n.test) for n in tree.body)
    return has_main and guarded


def cli_modules(root: Path = ROOT) -> list[str]:
    """``python -m`` entry points of the five packages and of ``benchmarks/``, e.g.
    ``"ddpg_her.train"``, ``"benchmarks.env_steps"``."""
    benches = {f"benchmarks.{p.stem}": p for p in sorted((root / "benchmarks").glob("*.py"))
               if p.stem != "__init__"}
    return [name for name, path in {**package_modules(root), **benches}.items()
            if _is_script(path)]


def example_scripts(root: Path = ROOT) -> list[str]:
    """Command-line scripts under ``examples/``, as paths relative to the repository root."""
    return [str(p.relative_to(root)) for p in sorted((root / "examples").glob("*.py"))
            if _is_script(p)]


def load(target: str) -> ModuleType:
    """A CLI module by dotted name, or an example script by its path (``examples/x.py``)."""
    if target.endswith(".py"):
        path = ROOT / target
        spec = importlib.util.spec_from_file_location(f"_cli_{path.stem}", path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    return importlib.import_module(target)


class _Caught(Exception):
    def __init__(self, parser: argparse.ArgumentParser, args: Any = None) -> None:
        super().__init__(parser.prog)
        self.parser = parser
        self.args = args


@contextlib.contextmanager
def _catch_parsers() -> Iterator[None]:
    original = argparse.ArgumentParser.parse_args

    def catch(self, *args, **kwargs):
        raise _Caught(self, args[0] if args else kwargs.get("args"))

    argparse.ArgumentParser.parse_args = catch  # type: ignore[method-assign]
    try:
        yield
    finally:
        argparse.ArgumentParser.parse_args = original  # type: ignore[method-assign]


def parser_of(target: str) -> argparse.ArgumentParser:
    """The parser that ``main`` of a CLI module or example script builds (nothing is run)."""
    module = load(target)
    with _catch_parsers():
        try:
            module.main([])
        except _Caught as caught:
            return caught.parser
    raise AssertionError(f"{target}: main() returned without calling parse_args")


def parse_as_main(target: str, argv: list[str]) -> argparse.Namespace:
    """Parse ``argv`` the way ``main(argv)`` of a CLI would, subcommands included (``main``
    picks the parser and the arguments it gets), without running anything after parsing."""
    module = load(target)
    with _catch_parsers():
        try:
            module.main(list(argv))
        except _Caught as caught:
            parser, args = caught.parser, caught.args
        else:
            raise AssertionError(f"{target}: main() returned without calling parse_args")
    return parser.parse_args(args)


def options(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    """Every flag and positional of ``parser`` except ``--help``."""
    return [a for a in parser._actions if not isinstance(a, argparse._HelpAction)]


def takes_a_number(action: argparse.Action) -> bool:
    """Whether the flag's value is an int or a float (a count, a quantity or a seed)."""
    return action.nargs != 0 and action.type in (int, float)


def split_command(line: str) -> tuple[str, list[str]] | None:
    """``("ddpg_her.train", argv)`` for ``python -m ddpg_her.train ...`` (or ``("examples/x.py",
    argv)`` for ``python examples/x.py ...``); None for any other line. Comments are dropped."""
    words = shlex.split(line, comments=True)
    if len(words) >= 3 and words[0] == "python" and words[1] == "-m":
        return words[2], words[3:]
    if len(words) >= 2 and words[0] == "python" and words[1].startswith("examples/"):
        return words[1], words[2:]
    return None

"""Benchmarks of the project's packages, outside the installed packages: each module is a
command (``python -m benchmarks.NAME --help`` from the repository root) whose recorded results
live under ``results/``; none is a test."""

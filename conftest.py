"""Loaded by pytest before it collects anything (the package modules too, for their doctests).

Triton reads TRITON_INTERPRET when a kernel module is imported, and --doctest-modules imports
envs.physics.triton_kernel before the tests' own files: without a GPU the Triton tests run on
Triton's CPU interpreter, so the variable is set here first. With a GPU it is left alone, and
the kernel compiles for the device."""

import os

import torch

if not torch.cuda.is_available():
    os.environ.setdefault("TRITON_INTERPRET", "1")

"""The one description of what a user may type: kinds of value (`Kind`: a type and range, in
words), records checked field by field against them (`check_fields`: the agent's configuration,
the task, ...), and the array checks of ur5kin's functions. Each error is one line naming the
value and what was expected.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import numbers
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

MOVING_JOINTS_RANGE = (1, 6)
"""Fewest and most moving joints of a sub-chain (joints 1..n move; the task itself uses 2..6,
:data:`envs.spec.N_JOINTS_RANGE`)."""

ROTATION_TOL = 1e-6
"""Largest deviation of ``R^T R`` from the identity, and of ``det R`` from 1, accepted in a pose."""


def _describe(x: Any) -> str:
    text = np.array2string(np.asarray(x), threshold=12, precision=6)
    return text if len(text) < 200 else text[:200] + "..."


def real_array(x: Any, name: str, what: str) -> np.ndarray:
    """Return ``x`` as a float64 array, or raise ``ValueError`` naming ``name`` and ``what``.

    Complex input is refused rather than cast (numpy's cast drops the imaginary part with only
    a warning); so are strings, None and other objects that are not real numbers. Booleans and
    integers are taken as numbers.
    """
    arr = np.asarray(x)
    if arr.dtype.kind not in "biuf":
        try:
            if arr.dtype.kind == "c":
                raise TypeError("complex")
            arr = np.asarray(x, dtype=float)
        except (TypeError, ValueError) as err:
            raise ValueError(f"{name} must be real numbers ({what}); got "
                             + "complex " * (arr.dtype.kind == "c") + _describe(x)) from err
    return arr.astype(float, copy=False)


def joint_array(q: Any, name: str = "q", n: int = 6, what: str = "joint angles in rad"
                ) -> np.ndarray:
    """Return ``q`` as a finite, real float64 array of shape ``(..., n)``, or raise ``ValueError``.

    Parameters
    ----------
    q : array_like, (..., n) float, rad
    name : str
        Name used in the error message.
    n : int
        Expected trailing dimension.
    what : str
        What the values are, with their unit, for the error message.
    """
    arr = real_array(q, name, what)
    if arr.ndim == 0 or arr.shape[-1] != n:
        describe = f"{what}, joints 1-{n}" if what == "joint angles in rad" else what
        raise ValueError(f"{name} must have shape (..., {n}) ({describe}); got shape {arr.shape}")
    check_finite(arr, name)
    return arr


def joint_count(n: Any, name: str = "n_joints") -> int:
    """Return ``n`` as an int in :data:`MOVING_JOINTS_RANGE`, or raise ``ValueError``."""
    return integer(*MOVING_JOINTS_RANGE, note="joints 1..n move")(name, n)


def check_finite(arr: np.ndarray, name: str) -> None:
    """Raise ``ValueError`` naming the first non-finite entry of ``arr``."""
    finite = np.isfinite(arr)
    if not finite.all():
        where = tuple(int(i) for i in np.argwhere(~finite)[0])
        raise ValueError(
            f"{name} must be finite; {name}[{', '.join(map(str, where))}] = {arr[where]}"
        )


def pose_array(pose: Any, name: str = "pose") -> np.ndarray:
    """Return ``pose`` as a float64 ``(..., 4, 4)`` rigid transform, or raise ``ValueError``.

    A rigid transform has an orthonormal rotation block with determinant +1 (to
    :data:`ROTATION_TOL`) and a last row of ``[0, 0, 0, 1]``.
    """
    arr = real_array(pose, name, "a 4 x 4 homogeneous transform, translation in m")
    if arr.ndim < 2 or arr.shape[-2:] != (4, 4):
        raise ValueError(f"{name} must have shape (..., 4, 4); got shape {arr.shape}")
    check_finite(arr, name)
    rot = arr[..., :3, :3]
    ortho = np.abs(np.swapaxes(rot, -1, -2) @ rot - np.eye(3)).max(axis=(-2, -1))
    det = np.linalg.det(rot)
    bottom = np.abs(arr[..., 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=-1)
    bad = (ortho > ROTATION_TOL) | (np.abs(det - 1.0) > ROTATION_TOL) | (bottom > 0.0)
    if np.any(bad):
        idx = tuple(int(i) for i in np.argwhere(np.atleast_1d(bad))[0]) if bad.ndim else ()
        one = arr[idx] if idx else arr
        raise ValueError(
            f"{name} must be a rigid transform (orthonormal rotation with det +1 within "
            f"{ROTATION_TOL}, last row [0, 0, 0, 1]); got {_describe(one)}"
        )
    return arr


class Kind(NamedTuple):
    """What a value may be: ``words`` (the "expected ..." of the error and of ``--help``), its
    ``test``, and ``cast``, the value as it is stored once it passed."""

    words: str
    test: Callable[[Any], bool]
    cast: Callable[[Any], Any] = lambda v: v
    parse: Callable[[str], Any] = str
    """How a command line's text becomes the value (`read`)."""

    def __call__(self, name: str, value: Any) -> Any:
        """``value`` cast, or a one-line ``ValueError`` naming ``name``, the value and words."""
        if not holds(self.test, value):
            raise ValueError(f"{name}={value!r:.200} (expected {self.words})")
        return self.cast(value)

    def read(self, text: str) -> Any:
        """The argparse ``type`` of a flag of this kind: argparse names the flag, this line
        the text and what was expected (``argument --seed: -1 (expected an integer >= 0)``)."""
        try:
            return self("", self.parse(text))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text} (expected {self.words})") from None


def holds(test: Callable[..., bool], *args: Any) -> bool:
    """Whether ``test(*args)`` is true; a value of the wrong type (a string, None) is not."""
    try:
        return bool(test(*args))
    except (TypeError, ValueError):
        return False


def is_integer(x: Any) -> bool:
    return isinstance(x, numbers.Integral) and not isinstance(x, bool | np.bool_)


def number(lo: float = -math.inf, hi: float = math.inf, *, above: bool = False,
           below: bool = False, finite: bool = True, note: str = "") -> Kind:
    """A real number in [lo, hi] (``above``: > lo, ``below``: < hi), finite unless ``finite`` is
    False; stored as a float. ``note`` (a unit) follows the words in parentheses."""
    span = (f"in {'(['[not above]}{lo:g}, {hi:g}{')]'[not below]}" if -math.inf < lo and
            hi < math.inf else f"{'>' if above else '>='} {lo:g}" if -math.inf < lo else
            f"{'<' if below else '<='} {hi:g}" if hi < math.inf else "")
    finite_words = finite and not -math.inf < lo <= hi < math.inf  # a closed span says it
    words = f"a{' finite' * finite_words} number {span}".strip() + (f" ({note})" if note else "")
    return Kind(words, lambda v: isinstance(v, numbers.Real) and not isinstance(v, bool | np.bool_)
                and (math.isfinite(v) or (not finite and v == v)) and (lo < v if above else lo <= v)
                and (v < hi if below else v <= hi), float, float)


def integer(lo: int, hi: int | None = None, note: str = "") -> Kind:
    """An integer in lo..hi (no upper bound when ``hi`` is None), stored as an int."""
    words = f"an integer {f'in {lo}..{hi}' if hi is not None else f'>= {lo}'}"
    return Kind(words + (f" ({note})" if note else ""), lambda v: is_integer(v) and lo <= v
                and (hi is None or v <= hi), int, int)


FLAG = Kind("True or False", lambda v: isinstance(v, bool | np.bool_), bool)
"""A flag, stored as a Python bool."""

COUNT = integer(1)
"""A count of things (goals, episodes, rounds), at least one."""

SEED = integer(0, note="numpy's seeds are")
"""A seed of ``numpy.random.default_rng`` (and of torch)."""


def choice(options: Sequence[Any], cast: Callable[[Any], Any] = lambda v: v) -> Kind:
    """One of ``options`` (an Enum's values when ``cast`` is the Enum)."""
    values = [getattr(o, "value", o) for o in options]
    return Kind(f"one of {values}", lambda v: getattr(v, "value", v) in values, cast)


def vector(n: int, unit: str, positive: bool = False) -> Kind:
    """``n`` finite numbers (> 0 when ``positive``), stored as a tuple of floats."""
    each = number(0, above=positive) if positive else number()  # not text numpy would cast

    def test(v: Any) -> bool:
        arr = np.asarray(v, dtype=object)
        return arr.shape == (n,) and all(holds(each.test, x) for x in arr)
    return Kind(f"{n} finite numbers{' > 0' * positive} ({unit})", test,
                lambda v: tuple(float(x) for x in v))


def kinds(*groups: tuple[Any, ...]) -> dict[str, Kind]:
    """``{field: kind}`` from groups ``(kind, field, field, ...)`` of fields that share a kind."""
    return {name: kind for kind, *names in groups for name in names}


def known_fields(cls: type, data: Mapping[str, Any], what: str) -> None:
    """Raise ``ValueError`` naming the keys of ``data`` that are no fields of dataclass ``cls``."""
    names = {f.name for f in dataclasses.fields(cls)}
    if unknown := sorted(set(data) - names):
        raise ValueError(f"unknown {what} field(s) {unknown}; the fields are {sorted(names)}")


Combination = tuple[str, str, Callable[[Any], bool]]
"""What a field may be combined with: (the fields the rule joins, ``", "``-separated, each
named with its value in a refusal; the rule in words; the test of the record)."""


def check_fields(record: Any, fields: Mapping[str, Kind], what: str,
                 combinations: Sequence[Combination] = ()) -> None:
    """Check and cast each field of the frozen dataclass ``record`` named in ``fields``, then
    the ``combinations``; one ``ValueError`` names every bad field, its value and what was
    expected: ``invalid {what}: gamma=2 (expected a number in [0, 1])``."""
    bad = []
    for name, kind in fields.items():
        value = getattr(record, name)
        if holds(kind.test, value):
            object.__setattr__(record, name, kind.cast(value))
        else:
            bad.append(f"{name}={value!r:.200} (expected {kind.words})")
    bad += [] if bad else [", ".join(f"{n}={getattr(record, n)!r:.200}" for n in names.split(", "))
                           + f" (expected {words})"
                           for names, words, test in combinations if not holds(test, record)]
    if bad:
        raise ValueError(f"invalid {what}: " + ", ".join(bad))

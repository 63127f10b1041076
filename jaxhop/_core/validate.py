"""Validation of user numbers: fields of terrain and course files, command-line options.

Every check raises `InputError` with one line that names the field and the rule it breaks
(`blocks[2].height: must be finite, got nan`, `--dy: must be positive, got 0`); the command
line prints it and exits with status 2. `arg_type` turns a check into an argparse `type=`
function, so that a bad option fails while the arguments are parsed, before any work.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from .errors import InputError


def short(value, n: int = 40) -> str:
    """`repr(value)`, cut to `n` characters (a user's value quoted in a message)."""
    text = repr(value)
    return text if len(text) <= n else text[: n - 3] + "..."


# --- numbers in files -------------------------------------------------------------------


def number(value, field: str, limit: float | None = None, *, positive: bool = False,
           nonneg: bool = False) -> float:
    """A JSON number as a finite float: not a bool or a string, `|value| <= limit`.

    With `positive` it must be `> 0`, with `nonneg` `>= 0`.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise InputError(f"{field}: expected a number, got {short(value)}")
    try:
        value = float(value)
    except OverflowError:
        raise InputError(f"{field}: number too large, got {short(value)}") from None
    if not math.isfinite(value):
        raise InputError(f"{field}: must be finite, got {value!r}")
    if positive and value <= 0:
        raise InputError(f"{field}: must be > 0, got {value!r}")
    if nonneg and value < 0:
        raise InputError(f"{field}: must be >= 0, got {value!r}")
    if limit is not None and abs(value) > limit:
        raise InputError(f"{field}: |{value:g}| exceeds the limit {limit:g}")
    return value


# --- numbers on the command line ----------------------------------------------------------


def numbers(text: str, field: str, n: int) -> list[float]:
    """`n` comma-separated finite numbers (`--apex 0.6,1.6,0.5`)."""
    if not isinstance(text, str):  # argparse turns a bare "--" value into a list
        raise InputError(f"{field}: expected {n} comma-separated numbers, got {text!r}")
    parts = text.split(",")
    if len(parts) != n:
        raise InputError(f"{field}: expected {n} comma-separated numbers, got {text!r}")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise InputError(f"{field}: expected numbers, got {text!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise InputError(f"{field}: numbers must be finite, got {text!r}")
    return values


def bounded(values, field: str, limit: float):
    """`values` unchanged if every one has magnitude at most `limit` (absurd sizes are errors)."""
    for v in values:
        if abs(v) > limit:
            raise InputError(f"{field}: |{v:g}| exceeds the limit {limit:g}")
    return values


def real(text: str, field: str, limit: float | None = None) -> float:
    """One finite number, with `|value| <= limit` where a limit is given."""
    (v,) = numbers(text, field, 1)
    return v if limit is None else bounded([v], field, limit)[0]


def positive(text: str, field: str) -> float:
    """One finite number `> 0`."""
    v = real(text, field)
    if v <= 0:
        raise InputError(f"{field}: must be positive, got {text}")
    return v


def _whole(text: str, field: str, what: str) -> int:
    if not isinstance(text, str):
        raise InputError(f"{field}: expected {what}, got {text!r}")
    try:
        return int(text)
    except ValueError:
        raise InputError(f"{field}: expected {what}, got {text!r}") from None


def count(text: str, field: str, hi: int) -> int:
    """A whole number in `[1, hi]` (`--max-steps`, `--chunk`): 2.5 is an error, not 2."""
    v = _whole(text, field, "a whole number")
    if not 1 <= v <= hi:
        raise InputError(f"{field}: must lie in [1, {hi}], got {v}")
    return v


def seed(text: str, field: str = "--seed") -> int:
    """A seed: a whole number in `[0, 2**63)`."""
    v = _whole(text, field, "a non-negative integer")
    if v < 0 or v >= 2**63:
        raise InputError(f"{field}: expected a non-negative integer below 2**63, got {text}")
    return v


def arg_type(check, field: str, *args, **kwargs):
    """An argparse `type=` function: `check(text, field, *args, **kwargs)`.

    argparse names the option in front of the message itself (`argument --dy: ...`), so the
    message loses its own `field: ` prefix; the jaxhop parser drops the word `argument`.
    """

    def parse(text):
        try:
            return check(text, field, *args, **kwargs)
        except InputError as err:
            raise argparse.ArgumentTypeError(str(err).removeprefix(f"{field}: ")) from None

    parse.__name__ = field.lstrip("-")
    return parse

"""Argument types shared by every command's parser: whole numbers and finite numbers with a
lower bound, each refusing anything else with one line (argparse prints it and exits 2).

They sit at the bottom of the package, beside the errors, so that a command defined in a
lower layer (bench, target, harden, tune) can use them without importing the CLI above it."""
from __future__ import annotations

import argparse
import math


def count_arg(text: str) -> int:
    """A whole number >= 0, written as an integer or as 1e7."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}") from None
    if not (v >= 0 and v == int(v) and v < 2**63):
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}")
    return int(v)


def _int_at_least(text: str, low: int) -> int:
    try:
        v = int(text)
    except ValueError:
        v = low - 1
    if v < low:
        raise argparse.ArgumentTypeError(f"expected a whole number >= {low}, got {text!r}")
    return v


def nonneg_int_arg(text: str) -> int:
    return _int_at_least(text, 0)


def positive_int_arg(text: str) -> int:
    return _int_at_least(text, 1)


def nonneg_float_arg(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0, got {text!r}")
    return v


def positive_float_arg(text: str) -> float:
    try:
        v = nonneg_float_arg(text)
    except argparse.ArgumentTypeError:
        v = 0.0
    if v == 0:
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return v

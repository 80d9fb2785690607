"""argparse value types shared by the console scripts (experiment, labelling)."""

import argparse
import math


def positive_int(text: str) -> int:
    """An integer >= 1."""
    return _int_at_least(text, 1)


def non_negative_int(text: str) -> int:
    """An integer >= 0."""
    return _int_at_least(text, 0)


def positive_float(text: str) -> float:
    """A finite float > 0."""
    return _finite_float(text, zero=False)


def non_negative_float(text: str) -> float:
    """A finite float >= 0."""
    return _finite_float(text, zero=True)


def _int_at_least(text: str, lowest: int) -> int:
    value = int(text)
    if value < lowest:
        raise argparse.ArgumentTypeError(f"must be >= {lowest}, got {value}")
    return value


def _finite_float(text: str, zero: bool) -> float:
    value = float(text)
    if not (math.isfinite(value) and (value > 0.0 or (zero and value == 0.0))):
        raise argparse.ArgumentTypeError(
            f"must be finite and {'>=' if zero else '>'} 0, got {text}")
    return value

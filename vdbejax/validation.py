"""Input checks shared by every public entry point and the CLI.

Each check raises ``ValueError`` with one line naming the parameter, the value and what
is allowed, so the CLI can print it and exit 2.
"""
from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any


def _fail(name: str, value: Any, allowed: str) -> None:
    raise ValueError(f"{name}={value!r} is invalid: {allowed}")


def _is_number(value: Any) -> bool:
    try:
        float(value)
    except (TypeError, ValueError):
        return False
    return not isinstance(value, (bool, str))


def check_choice(name: str, value: Any, allowed: Iterable[str]) -> str:
    allowed = tuple(allowed)
    if value not in allowed:
        _fail(name, value, "must be one of " + ", ".join(allowed))
    return value


def check_in_range(
    name: str,
    value: Any,
    low: float,
    high: float,
    *,
    low_open: bool = False,
    high_open: bool = False,
) -> float:
    """Check ``value`` is a finite number in the interval (described in the message)."""
    lo_b, hi_b = ("(" if low_open else "["), (")" if high_open else "]")
    interval = f"{lo_b}{low:g}, {high:g}{hi_b}"
    if not _is_number(value) or math.isnan(float(value)):
        _fail(name, value, f"must be a number in {interval}")
    v = float(value)
    ok_low = v > low if low_open else v >= low
    ok_high = v < high if high_open else v <= high
    if not (ok_low and ok_high):
        _fail(name, value, f"must be in {interval}")
    return v


def check_positive(name: str, value: Any, *, allow_inf: bool = False) -> float:
    if not _is_number(value) or math.isnan(float(value)) or float(value) <= 0:
        _fail(name, value, "must be a number > 0")
    if math.isinf(float(value)) and not allow_inf:
        _fail(name, value, "must be a finite number > 0")
    return float(value)


def check_finite(name: str, value: Any) -> float:
    if not _is_number(value) or not math.isfinite(float(value)):
        _fail(name, value, "must be a finite number")
    return float(value)


def check_int(name: str, value: Any, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, (int,)) and not (
        hasattr(value, "__index__")
    ):
        _fail(name, value, f"must be an integer >= {minimum}")
    if int(value) < minimum:
        _fail(name, value, f"must be an integer >= {minimum}")
    return int(value)


def check_explorer(
    name: str, param: Any, *, tie_break: str = "random", delta: Any = 0.1, tau: Any = 0.001
) -> None:
    """Check an explorer's name, its swept parameter and its fixed options."""
    from vdbejax.explorers import EXPLORERS, TIE_BREAKS

    check_choice("explorer", name, EXPLORERS)
    check_choice("tie_break", tie_break, TIE_BREAKS)
    if name == "egreedy":
        check_in_range("epsilon", param, 0.0, 1.0)
    elif name == "softmax":
        check_positive("tau", param)
    else:
        check_positive("sigma", param)
        check_in_range("delta", delta, 0.0, 1.0, low_open=True)
        if name == "vdbe_softmax":
            check_positive("tau", tau)


def check_learner(name: str, *, alpha: Any, gamma: Any, q_init: Any) -> None:
    """Check a learner's name, α, γ and initial Q value."""
    from vdbejax.learners import LEARNERS

    check_choice("learner", name, LEARNERS)
    check_in_range("alpha", alpha, 0.0, 1.0, low_open=True)
    check_in_range("gamma", gamma, 0.0, 1.0)
    check_finite("q_init", q_init)

"""Wall-clock budgets (``--minutes`` of train and adapt) checked before the work: one line, not an overflow later."""
from __future__ import annotations

import math

from .errors import ConfigError

#: the longest wall-clock budget ``--minutes`` takes (train, adapt): a week; beyond that it is a typo, and
#: 1e308 minutes overflowed the end-time line
MAX_BUDGET_MINUTES = 7 * 24 * 60.0


def check_budget_minutes(value, flag: str = "--minutes", allow_zero: bool = True) -> float:
    """``value`` as minutes of a wall-clock budget: a finite number ≥ 0 (> 0 where not ``allow_zero``) and at most
    `MAX_BUDGET_MINUTES`; `ConfigError` in one line otherwise."""
    low = "≥ 0 (0: no budget)" if allow_zero else "> 0"
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or (
            value < 0 or (value == 0 and not allow_zero)):
        raise ConfigError(f"{flag} {value!r}: give a budget in minutes {low}, at most {MAX_BUDGET_MINUTES:g} (a week)")
    if value > MAX_BUDGET_MINUTES:
        raise ConfigError(f"{flag} {value:g}: budgets beyond a week ({MAX_BUDGET_MINUTES:g} minutes) are refused; give "
                          f"at most {MAX_BUDGET_MINUTES:g}" + (" (0: no budget, --epochs alone)" if allow_zero else ""))
    return float(value)

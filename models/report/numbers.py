"""The report's one number formatter: a number (or an RGB triple) as table text, a placeholder for
a missing or non-finite value (``docs/report.md``)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

#: the text of a missing value, unless a caller's format keeps its own
MISSING = "–"


def number(x: Any, spec: str = ".3g", missing: str = MISSING) -> str:
    """``x`` formatted with ``spec``: ``missing`` for None or a non-finite number; an RGB triple of
    equal channels as one number, other arrays as their values separated by spaces."""
    if x is None:
        return missing
    if isinstance(x, (list, tuple, np.ndarray)):
        a = np.atleast_1d(np.asarray(x, dtype=float))
        if a.size == 3 and np.ptp(a) == 0:
            a = a[:1]
        return " ".join(number(float(v), spec, missing) for v in a)
    v = float(x)
    return format(v, spec) if math.isfinite(v) else missing

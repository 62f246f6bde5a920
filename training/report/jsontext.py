"""JSON text of results for readers other than Python: no NaN or Infinity literals."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np


def finite_or_null(obj: Any) -> Any:
    """obj with every non-finite float (NaN, ±inf; numpy's too) replaced by None, through
    dicts, lists and tuples: standard JSON has no NaN or Infinity (jq, JavaScript and
    pandas' strict readers refuse them)."""
    if isinstance(obj, dict):
        return {k: finite_or_null(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_null(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return obj


def json_text(obj: Any, indent: int | None = 1) -> str:
    """obj as standard JSON (finite_or_null), e.g. for `--json` output."""
    return json.dumps(finite_or_null(obj), indent=indent, allow_nan=False)

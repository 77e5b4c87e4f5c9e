"""Small helpers the CLI commands share: JSON output, ledger tables, atomic writes."""

from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from core.cost import CostLedger


def _clean(obj: Any) -> Any:
    if isinstance(obj, float):
        return None if not math.isfinite(obj) else obj
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    return obj


def dumps(obj: Any) -> str:
    return json.dumps(_clean(obj), indent=2, ensure_ascii=False)


def ledger_table(ledger: CostLedger) -> str:
    total = ledger.total_s
    lines = [f"{'category':<12} {'seconds':>12} {'share':>7}"]
    for cat, sec in ledger.seconds.items():
        if sec:
            lines.append(f"{cat:<12} {sec:>12,.1f} {100 * sec / total:>6.1f}%")
    lines.append(f"{'total':<12} {total:>12,.1f}  ({total / 3600:.2f} h)")
    return "\n".join(lines)


def write_atomic(path: str | Path, text: str) -> None:
    """Write to a temporary file beside the target, then rename: never half-written."""
    target = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent or ".")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def positive_float(flag: str) -> Callable[[str], float]:
    """An argparse type: a finite number > 0, with an error naming the flag."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag} must be a number, got {text!r}") from None
        if not math.isfinite(v) or v <= 0:
            raise argparse.ArgumentTypeError(f"{flag} must be > 0, got {text}")
        return v

    return parse


def whole_number(flag: str, lo: int, hi: int) -> Callable[[str], int]:
    """An argparse type: an integer in [lo, hi], with an error naming the flag."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag} must be a whole number, got {text!r}") from None
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"{flag} must be from {lo} to {hi}, got {v}")
        return v

    return parse


seed_arg = whole_number("--seed", 0, 2**32 - 1)

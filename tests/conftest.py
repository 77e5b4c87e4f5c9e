"""Shared test set-up: run from a checkout without installing, and locate the shared instrument files."""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

os.environ.setdefault("OMP_NUM_THREADS", "1")

from apprise_receiver import Receiver  # noqa: E402 (tests/ is on sys.path once this file is imported)

SHARED = Path(os.environ.get("AENI_SHARED", ROOT.parent / "shared"))
KLA_DIR = SHARED / "data" / "kla"


@pytest.fixture
def kla_dir() -> Path:
    if not KLA_DIR.is_dir():
        pytest.skip(f"real KLA export files not found at {KLA_DIR} (../shared is absent in a user's clone)")
    return KLA_DIR


@pytest.fixture
def live_run(tmp_path: Path):  # type: ignore[no-untyped-def]
    """Start real test runs (``aeni_console.testkit.live.LiveRun``); each is stopped when the test ends."""
    from aeni_console.testkit.live import LiveRun

    runs: list[LiveRun] = []

    def start(**kwargs: object) -> LiveRun:
        run = LiveRun(tmp_path, name=f"run{len(runs)}", **kwargs)  # type: ignore[arg-type]
        runs.append(run)
        run.start()
        return run

    yield start
    for run in runs:
        run.close()


@pytest.fixture
def receiver() -> Iterator[Receiver]:
    """A running apprise json:// receiver on 127.0.0.1 (``tests/apprise_receiver.py``), stopped after the test."""
    r = Receiver()
    r.thread.start()
    yield r
    r.server.shutdown()

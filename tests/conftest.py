"""Shared test set-up: run from a checkout without installing, and locate the shared instrument files."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

os.environ.setdefault("OMP_NUM_THREADS", "1")

SHARED = Path(os.environ.get("AENI_SHARED", ROOT.parent / "shared"))
KLA_DIR = SHARED / "data" / "kla"


@pytest.fixture
def kla_dir() -> Path:
    if not KLA_DIR.is_dir():
        pytest.skip(f"real KLA export files not found at {KLA_DIR} (../shared is absent in a user's clone)")
    return KLA_DIR

"""What a reader returns: one ``KlaIndent`` per test, gathered in a ``KlaExport`` with its notes."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import pandas as pd

NO_POSITIONS = "no positions in the export"


SOFTWARE_INVIEW = "InView"


SOFTWARE_NANOSUITE = "NanoSuite"


SOFTWARE_TESTWORKS = "TestWorks"


SOFTWARE_HYSITRON = "Hysitron"


SOFTWARE_ANTON_PAAR = "Anton Paar"


SOFTWARE_MICRO_MATERIALS = "Micro Materials"


SOFTWARE_FISCHERSCOPE = "Fischerscope"


SOFTWARE_UNKNOWN = "unknown"


@dataclass(frozen=True)
class KlaIndent:
    """One test of a KLA export; ``None`` where the file does not say (or says "invalid")."""

    test_id: str
    x_um: float | None
    y_um: float | None
    hardness_gpa: float | None
    modulus_gpa: float | None
    drift_rate_nm_s: float | None
    max_load_mn: float | None
    max_depth_nm: float | None
    source: str  # "results", "curve" (computed from its load-depth curve) or "record" (a per-test record)
    # why this indent has no usable hardness (blank, "--", 1.797e308, zero/negative/impossible value);
    # None for a measured indent. A failed indent never carries a hardness number.
    failure: str | None = None

    @property
    def failed(self) -> bool:
        return self.failure is not None


@dataclass(frozen=True)
class KlaExport:
    path: str
    software: str  # the format recognised: InView, NanoSuite, TestWorks, Hysitron, Anton Paar ... or unknown
    indents: tuple[KlaIndent, ...]
    warnings: tuple[str, ...] = ()
    # the depth range (nm) the hardness column says it was averaged over, e.g. "Avg Hardness [75-85 nm]"
    hardness_range_nm: tuple[float, float] | None = None
    hardness_column: str = ""  # the column the hardness came from ("load-depth curve" when derived)
    # how values computed from curves were computed: the method, the area function, the frame compliance
    analysis: str = ""

    @property
    def has_positions(self) -> bool:
        return any(i.x_um is not None and i.y_um is not None for i in self.indents)

    @property
    def summary(self) -> str:
        """One line for logs and the manifest: the format, the tests, where hardness came from."""
        where = f", hardness from {self.hardness_column!r}" if self.hardness_column else ""
        xy = "" if self.has_positions else ", no positions"
        return f"{Path(self.path).name}: format {self.software}, {len(self.indents)} tests{where}{xy}"

    def to_frame(self) -> pd.DataFrame:
        columns = [f.name for f in fields(KlaIndent)]
        frame = pd.DataFrame([asdict(i) for i in self.indents], columns=columns)
        numeric = [c for c in columns if c not in ("test_id", "source", "failure")]
        frame[numeric] = frame[numeric].astype(float)
        return frame


def records(export: KlaExport) -> list[dict[str, Any]]:
    """JSON-ready dicts (None for missing), one per indent."""
    return [asdict(i) for i in export.indents]

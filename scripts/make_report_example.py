"""Write docs/report-example/: `aeni report` on a short supervised demo run (one jump vetoed, the rest approved).

Deterministic (seed 0, emulator). Run: python scripts/make_report_example.py
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aeni_console.reports.run import write_report  # noqa: E402
from aeni_console.testkit.scripted import run_supervised  # noqa: E402

OUT = ROOT / "docs" / "report-example"


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        journal = run_supervised(
            Path(tmp) / "demo.sqlite",
            {"name": "demo", "campaign.seed": 0, "planner.budget_s": 40_000},
            answers=("veto", "approve", "approve", "veto"),
        )
        written = write_report(journal, OUT)
    summary = OUT / "summary.md"
    text = summary.read_text(encoding="utf-8")
    # the journal lived in a temporary folder: name it as a user would see it
    lines = [
        ("- journal: `runs/<UTC time>-demo.sqlite`" if ln.startswith("- journal:") else ln)
        for ln in text.splitlines()
    ]
    summary.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print(f"wrote {', '.join(p.name for p in written)} to {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

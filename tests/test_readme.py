"""The README's two fresh-machine commands stay true: CI runs the same test command."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _bash_blocks(text: str) -> list[str]:
    return [b.strip() for b in re.findall(r"```bash\n(.*?)```", text, flags=re.S)]


def test_readme_has_exactly_the_two_setup_commands_and_ci_runs_the_test_one() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    setup = readme.split("## Set up on a fresh machine", 1)[1].split("\n## ", 1)[0]
    blocks = _bash_blocks(setup)
    assert len(blocks) == 2
    main_cmd, test_cmd = blocks
    for cmd in blocks:
        # torch's CPU build first, or pip pulls the CUDA one
        assert cmd.index("torch==2.13.0") < cmd.index("pip install -q -e")
    assert main_cmd.endswith("aeni demo")
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert test_cmd in ci.splitlines()


def test_core_and_drivers_never_import_the_ui() -> None:
    pattern = re.compile(r"^\s*(from|import)\s+(textual|aeni_console)\b", re.M)
    offenders = [
        str(p.relative_to(ROOT))
        for pkg in ("core", "drivers")
        for p in (ROOT / pkg).rglob("*.py")
        if pattern.search(p.read_text(encoding="utf-8"))
    ]
    assert offenders == []

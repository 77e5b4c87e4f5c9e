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


def _aeni_commands(text: str) -> list[str]:
    """Every ``aeni ...`` command the README shows: the lines of its bash blocks and its inline code."""
    lines = [ln.split("  #", 1)[0].strip() for block in _bash_blocks(text) for ln in block.splitlines()]
    inline = re.findall(r"`(aeni [^`]+)`", text)
    return [c for c in dict.fromkeys([*lines, *inline]) if c.startswith("aeni ")]


def test_every_aeni_command_in_the_readme_parses() -> None:
    """A newcomer copies these: each must be a command the CLI knows, with flags it takes (parsed, not run:
    argparse is the dry form; a placeholder such as RUN or DIR stands where a user's path goes)."""
    import shlex

    from aeni_console.cli.main import build_parser

    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    commands = _aeni_commands(readme)
    assert len(commands) >= 15, commands
    parser = build_parser()
    for cmd in commands:
        argv = shlex.split(cmd)[1:]
        if argv == ["COMMAND", "--help"]:
            continue  # the README's pointer to every command's help, not a command
        try:
            args = parser.parse_args(argv)
        except SystemExit as exc:  # argparse refuses with exit 2
            raise AssertionError(f"README command does not parse: {cmd}") from exc
        assert callable(getattr(args, "func", None)), f"README command runs nothing: {cmd}"


def test_the_readme_stays_a_guide() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 250
    for link in re.findall(r"\]\((docs/[^)#]+)", readme):
        assert (ROOT / link).exists(), f"README links to a missing {link}"

"""`aeni kla check`: the first-run 3-site array tells a right set-up from a flipped, swapped or shifted one."""

from __future__ import annotations

import argparse
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from aeni_console.cli import kla as kla_command
from core.profile import load_profile
from drivers.kla.fake_inview import FakeInView, parse_fault
from drivers.sim.scenarios import make_scenario

FAST_TOML = 'extends = "kla-imicro"\n[inview]\nstable_polls = 2\npoll_s = 0.02\n'


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="aeni")
    kla_command.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return int(args.func(args))


@pytest.fixture
def profile_file(tmp_path: Path) -> Path:
    path = tmp_path / "fast.toml"
    path.write_text(FAST_TOML)
    return path


def serving(exchange: Path, profile_file: Path, *faults: str) -> Iterator[None]:
    fake = FakeInView(
        exchange,
        load_profile(profile_file),
        make_scenario("ternary", 0).make_emulator,
        faults=tuple(parse_fault(f) for f in faults),
        invalid_rate=0.0,
        write_s=0.02,
        log=lambda _line: None,
    )
    stop = threading.Event()
    thread = threading.Thread(target=fake.serve_forever, kwargs={"poll_s": 0.02, "stop": stop.is_set})
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


@pytest.mark.parametrize(
    ("faults", "code", "says"),
    [
        ((), 0, "RIGHT: the three indents landed on the planned sites"),
        (("flipped-y",), 1, "the Y axis is flipped (set inview.array_y_sign to the other sign)"),
        (("mm-um",), 0, "note: X/Y positions were mm labelled as µm"),
        (("missing-export",), 1, "NOT RIGHT: no export by the deadline"),
    ],
)
def test_check_array_verdicts(
    tmp_path: Path,
    profile_file: Path,
    capsys: pytest.CaptureFixture[str],
    faults: tuple[str, ...],
    code: int,
    says: str,
) -> None:
    exchange = tmp_path / "x"
    exchange.mkdir()
    argv = ["kla", "check", "--exchange", str(exchange), "--x-mm", "0.4", "--y-mm", "0.3"]
    timeout = "1" if "missing-export" in faults else "20"
    argv += ["--profile", str(profile_file), "--run", "chk", "--timeout-s", timeout]
    for _ in serving(exchange, profile_file, *faults):
        assert _run(argv) == code
    out = capsys.readouterr().out
    assert "TOKEN " in out and "X 0.4000 mm, Y 0.3000 mm" in out and "3 sites," in out
    assert says in out
    sites = (exchange / "outbox" / "chk-000-sites.txt").read_text().splitlines()
    assert sites == ["0, 0", "100, 0", "0, -50"]  # the L, with the profile's image-Y flip

"""A stretch through the KLA driver end to end: planned before an absence, handed to the operator in one
visit (every array's ticket out with the first, the ticket saying it is a stretch, how long it runs and the
arrays in load order), run by the fake InView array after array, every indent journaled; a kill -9 in the
middle and `aeni resume` continue the same stretch (nothing re-planned, lost or duplicated), and once the
operator is back the run plans adaptive blocks again."""

from __future__ import annotations

import itertools
import json
import signal
import sqlite3
import subprocess
from datetime import datetime, timedelta
from pathlib import Path

import pytest

from aeni_console.cli.main import main as cli_main
from core.profile import load_profile
from drivers.kla.exchange import Ticket
from drivers.kla.fake_inview import FakeInView
from drivers.sim.scenarios import make_scenario
from tests.test_kla_run import ENV, FAST_PROFILE, aeni, engine_state, wait_for

START_INDENTS = 64  # aeni's space-filling start: the stretch comes after it, so it is planned on the model


def _ticket(exchange: Path, block_id: int) -> Ticket | None:
    path = exchange / "outbox" / f"kla-{block_id:03d}-ticket.json"
    if not path.is_file():
        return None
    return Ticket.from_dict(json.loads(path.read_text()), str(path))


def _indents(journal: Path) -> list[tuple[int, int]]:
    with sqlite3.connect(journal) as conn:
        return list(
            conn.execute("SELECT block_id, indent_index FROM indents ORDER BY block_id, indent_index")
        )


def _decisions(journal: Path) -> list[tuple[int, str, str]]:
    with sqlite3.connect(journal) as conn:
        return list(conn.execute("SELECT block_id, phase, status FROM decisions ORDER BY decision_id"))


def _observed(journal: Path) -> set[int]:
    with sqlite3.connect(journal) as conn:
        return {b for (b,) in conn.execute("SELECT block_id FROM blocks WHERE status = 'observed'")}


def _last_state(journal: Path) -> dict[str, object]:
    with sqlite3.connect(journal) as conn:
        (text,) = conn.execute("SELECT state_json FROM campaign_states ORDER BY id DESC LIMIT 1").fetchone()
    state: dict[str, object] = json.loads(text)
    return state


def _send(journal: Path, *words: str) -> None:
    assert cli_main(["send", str(journal), *words]) == 0


@pytest.mark.slow
def test_a_stretch_runs_through_the_fake_inview_and_a_resume_continues_it(tmp_path: Path) -> None:
    exchange = tmp_path / "exchange"
    exchange.mkdir()
    profile_path = tmp_path / "fast.toml"
    profile_path.write_text(FAST_PROFILE)
    config = tmp_path / "run.toml"
    config.write_text(
        'name = "kla"\n[campaign]\npolicy = "aeni+stretch"\nscenario = "ternary"\nseed = 0\n'
        f'profile = "{profile_path}"\n[operator]\nhours = "always"\nresponse_min = 0\nvisit_every_min = 60\n'
    )
    journal = tmp_path / "runs" / "kla.sqlite"
    argv = aeni(
        "run", str(config), "--driver", "kla", "--exchange", str(exchange), "--budget-s", "40000",
        "--journal", str(journal), "--speed", "1e6", "--quiet",
    )  # fmt: skip
    profile = load_profile(str(profile_path))
    scenario = make_scenario("ternary", 0)
    served: list[int] = []

    def fake() -> FakeInView:  # the instrument PC: one array per call, as the operator loaded it
        return FakeInView(exchange, profile, lambda: scenario.make_emulator(profile), speed=1e6,
                          invalid_rate=0.0, write_s=0.0, log=lambda _line: None)  # fmt: skip

    def serve(block_id: int) -> Ticket:
        wait_for(lambda: _ticket(exchange, block_id) is not None)
        fake().serve(exchange / "outbox" / f"kla-{block_id:03d}-ticket.json")
        served.append(block_id)
        ticket = _ticket(exchange, block_id)
        assert ticket is not None
        return ticket

    engine = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT, env=ENV)
    try:
        # the space-filling start, adaptive blocks with someone there; the operator says they leave for
        # the evening before its last block ends
        block, made = 0, 0
        while True:
            wait_for(lambda b=block: _ticket(exchange, b) is not None, 120)
            ticket = _ticket(exchange, block)
            assert ticket is not None and ticket.stretch_index == 0
            if made + ticket.n_sites >= START_INDENTS:
                break
            serve(block)
            made += ticket.n_sites
            block += 1
        away = (datetime.now() + timedelta(hours=3, minutes=30)).replace(second=0, microsecond=0)
        _send(journal, "away-until", away.isoformat())
        serve(block)
        first = block + 1

        # one stretch before the absence: every array's ticket is out with the first
        wait_for(lambda: _ticket(exchange, first) is not None, 120)
        head = _ticket(exchange, first)
        assert head is not None and head.stretch_index == 1
        n = len(head.stretch_arrays)
        assert n >= 3
        wait_for(lambda: all(_ticket(exchange, first + k) is not None for k in range(n)))
        tickets = [_ticket(exchange, first + k) for k in range(n)]
        assert sum(t.expected_s for t in tickets if t is not None) == pytest.approx(head.stretch_s)
        assert [t.stretch_index for t in tickets if t is not None] == list(range(1, n + 1))
        text = (exchange / "outbox" / f"kla-{first:03d}-ticket.txt").read_text()
        assert f"STRETCH: array 1 of {n}" in text and "load all of them now, in this order" in text
        # it fills the absence of ~3.5 h: arrays are added until it is filled (the last may run on)
        assert head.stretch_s >= 3.0 * 3600
        assert sum(t.expected_s for t in tickets[:-1] if t is not None) < 3.5 * 3600
        assert f"~{head.stretch_s / 3600:.1f} h of instrument time" in text
        for k, t in enumerate(tickets, start=1):  # the arrays in load order, each with its method
            assert t is not None and len(t.methods) == 1  # one program: one method, one hold
            line = head.stretch_arrays[k - 1]
            assert line.startswith(f"{k}. block {first + k - 1}: outbox/{t.sites_file}")
            assert f'"{t.methods[0].method}"' in line
        # later arrays were loaded with the first; their deadlines follow the arrays before them
        assert all(a is not None and b is not None and a.deadline() <= b.deadline()
                   for a, b in itertools.pairwise(tickets))  # fmt: skip
        tokens = {t.block_id: t.token for t in tickets if t is not None}

        # array 1 runs; the engine dies while it waits for array 2's export
        serve(first)
        wait_for(lambda: first in _observed(journal), 120)
        wait_for(lambda: engine_state(journal).value == "waiting-for-instrument")
    finally:
        engine.send_signal(signal.SIGKILL)
        engine.wait()
    # the instrument goes on without the engine: array 2 runs and is exported
    serve(first + 1)
    resumed = subprocess.Popen(
        aeni("resume", str(journal), "--quiet"), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env=ENV,
    )  # fmt: skip
    try:
        # the resumed engine takes array 2's export and goes on with array 3 of the same stretch, still
        # knowing the operator is away
        wait_for(lambda: any(b == first + 2 for b, _, _ in _decisions(journal)), 120)
        assert _last_state(journal).get("away_until") == away.isoformat()
        # the operator comes back early; the stretch runs on as loaded
        _send(journal, "away-until", datetime.now().replace(microsecond=0).isoformat())
        for k in range(2, n):
            serve(first + k)
        after = first + n
        wait_for(lambda: _ticket(exchange, after) is not None, 120)
        _send(journal, "abort")
        out, _ = resumed.communicate(timeout=120)
        assert engine_state(journal).value == "stopped", out
    finally:
        if resumed.poll() is None:
            resumed.kill()
            resumed.communicate()

    # one stretch, planned once: its later arrays are decided as "stretch-continues", once each
    decisions = [(b, p) for b, p, s in _decisions(journal) if s == "auto"]
    stretch = [(b, p) for b, p in decisions if p.startswith("stretch")]
    assert stretch == [(first, "stretch")] + [(first + k, "stretch-continues") for k in range(1, n)]
    # the resumed run kept every ticket (same token) and re-planned nothing
    for block_id, token in tokens.items():
        t = _ticket(exchange, block_id)
        assert t is not None and t.token == token and t.stretch_index == block_id - first + 1
    # every array ran once and every indent is journaled once
    assert served.count(first + 1) == 1 and sorted(set(served)) == served
    rows = _indents(journal)
    assert len(rows) == len(set(rows))
    for block_id in range(first, first + n):
        t = _ticket(exchange, block_id)
        assert t is not None
        assert sorted(i for b, i in rows if b == block_id) == list(range(t.n_sites))
    # the operator is back: the next block is planned adaptively again, with its own ticket
    nxt = _ticket(exchange, after)
    assert nxt is not None and nxt.stretch_index == 0
    phases_after = [p for b, p in decisions if b == after]
    assert phases_after and not any(p.startswith("stretch") for p in phases_after)

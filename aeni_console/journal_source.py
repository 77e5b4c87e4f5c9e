"""The console's sources backed by a real run journal: a live run, and a finished run to step through.

``JournalSource`` is a thin, lock-guarded wrapper over ``core.journal.JournalReader`` (one reader per
console, used from the feed thread). ``JournalReplay`` rebuilds, from the journal's block records, the
snapshot the console would have shown just after each block finished, so an operator can walk a run
block by block and see the map, the ledger and the decision that came next.
"""

from __future__ import annotations

import threading
from dataclasses import replace
from datetime import datetime
from pathlib import Path
from typing import Any

from core.cost import indent_steps
from core.drift import AREA_ERROR_THRESHOLD_PCT, area_error_pct
from core.journal import BlockRecord, JournalReader, send_command
from core.plan import LEDGER_CATEGORIES, Decision
from core.runview import (
    Command,
    DriftStatus,
    GpStatus,
    LogEvent,
    MapFields,
    QueueItem,
    RunSnapshot,
    TestedCenter,
)

LOG_TAIL = 200


class JournalSource:
    """A live (or finished) run read from its journal; commands go into the journal's command table."""

    def __init__(self, path: str | Path, reader_user: str | int | None = None) -> None:
        self.path = Path(path)
        self.reader_user = reader_user
        self._lock = threading.Lock()
        self._reader = JournalReader(self.path)

    def snapshot(self) -> RunSnapshot:
        with self._lock:
            return self._reader.snapshot(self.reader_user)

    def map_fields(self, snapshot_id: int) -> MapFields | None:
        with self._lock:
            try:
                return self._reader.map_fields(snapshot_id)
            except KeyError:
                return None

    def send(self, command: Command) -> None:
        send_command(self.path, command)

    def close(self) -> None:
        with self._lock:
            self._reader.close()


def _wall_seconds(a: str, b: str) -> float:
    try:
        return max(
            (
                datetime.fromisoformat(b.replace("Z", "+00:00"))
                - datetime.fromisoformat(a.replace("Z", "+00:00"))
            ).total_seconds(),
            0.0,
        )
    except ValueError:
        return 0.0


class JournalReplay(JournalSource):
    """Step through a run: ``snapshot_at(i)`` is the view just after the i-th observed block."""

    def __init__(self, path: str | Path, reader_user: str | int | None = None) -> None:
        super().__init__(path, reader_user)
        self._records: list[BlockRecord] = []
        self._observed: list[BlockRecord] = []
        self._events: list[LogEvent] = []
        self._final: RunSnapshot | None = None

    def _load(self) -> None:
        with self._lock:
            self._final = self._reader.snapshot(self.reader_user)
            self._records = self._reader.blocks()
            self._events = self._reader.events()
        self._observed = [r for r in self._records if r.status == "observed" and r.results]

    def n_blocks(self) -> int:
        self._load()
        return len(self._observed)

    def send(self, command: Command) -> None:
        raise PermissionError("a replay cannot command the run; attach with `aeni console RUN` instead")

    def snapshot_at(self, block_index: int) -> RunSnapshot:
        if self._final is None:
            self._load()
        final = self._final
        assert final is not None
        if not 0 <= block_index < len(self._observed):
            raise IndexError(f"block index {block_index} is outside 0–{len(self._observed) - 1}")
        rec = self._observed[block_index]
        bid = rec.block.block_id
        upto = [r for r in self._records if r.block.block_id <= bid]
        ledger = dict.fromkeys(LEDGER_CATEGORIES, 0.0)
        n_reconf = 0
        for r in upto:
            for s in r.steps:
                ledger[s.category] = ledger.get(s.category, 0.0) + s.seconds
                n_reconf += s.category == "reconfigure"
        results = [res for r in upto for res in r.results]
        t_end = (
            rec.finished_t_s if rec.finished_t_s is not None else max((x.t_s for x in results), default=0.0)
        )
        tested = tuple(
            TestedCenter(r.block.center_x_um, r.block.center_y_um, r.block.block_id, float(r.median_gpa))
            for r in self._observed[: block_index + 1]
            if r.median_gpa is not None  # a block whose indents all failed has no centre value
        )
        later = [r for r in self._records if r.block.block_id > bid]
        nxt: Decision | None = later[0].decision if later else None
        last_pos = (results[-1].commanded_x_um, results[-1].commanded_y_um) if results else (0.0, 0.0)
        queue: list[QueueItem] = []
        if nxt is not None:
            eta, pos, is_open = 0.0, last_pos, True
            for i, spec in enumerate(nxt.block.indents):
                eta += sum(s.seconds for s in indent_steps(self._reader.profile, nxt.block, i, pos, is_open))
                pos = (spec.x_um, spec.y_um)
                queue.append(QueueItem(nxt.block.block_id, i, spec, nxt.block.grid_g, eta))
        rates = [(x.t_s, x.drift_rate_nm_s) for x in results]
        events = tuple((t, rate) for t, rate in rates if area_error_pct(rate) >= AREA_ERROR_THRESHOLD_PCT)
        last_rate = rates[-1][1] if rates else None
        d = rec.decision
        drift = DriftStatus(
            last_rate_nm_s=last_rate,
            hold_mode=f"{d.hold_mode} {rec.block.hold_s:g} s"
            if d is not None
            else f"fixed {rec.block.hold_s:g} s",
            area_error_pct=(
                d.area_error_pct
                if d is not None and d.area_error_pct is not None
                else (None if last_rate is None else area_error_pct(last_rate))
            ),
            threshold_pct=AREA_ERROR_THRESHOLD_PCT,
            events=events[-100:],
        )
        fs: dict[str, Any] = rec.fit_summary
        gp = GpStatus(
            lengthscales_um=tuple(fs.get("lengthscales_um", ()) or ()),
            noise_lengthscales_um=tuple(fs.get("noise_lengthscales_um", ()) or ()),
            collapse_alarm=bool(fs.get("collapse_alarm", False)),
            collapse_reason=str(fs.get("collapse_reason", "")),
            refit_s=fs.get("refit_s"),
            snapshot_id=rec.snapshot_id,
        )
        log = [e for e in self._events if e.t_s <= t_end + 1e-6]
        wall_s = _wall_seconds(self._events[0].wall_utc, log[-1].wall_utc) if log and self._events else 0.0
        return replace(
            final,
            can_command=False,
            instrument_s=float(t_end),
            wall_s=wall_s,
            n_indents=len(results),
            n_blocks=block_index + 1,
            reconfigurations=n_reconf,
            ledger={k: round(v, 6) for k, v in ledger.items()},
            queue=tuple(queue),
            current_block=None,
            pending=nxt,
            last_decision=d,
            drift=drift,
            gp=gp,
            mape_pct=fs.get("mape_pct"),
            max_found_gpa=fs.get("max_found_gpa"),
            tested=tested,
            log=tuple(log[-LOG_TAIL:]),
        )

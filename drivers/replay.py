"""A driver that plays back a finished journal: the same steps and indents, on the recorded clock.

It lets the engine (or a console's step-through) re-run a recorded run without an instrument or an
emulator. A block that is not in the journal, or whose plan differs from the recorded one, is refused:
replay never invents a measurement.
"""

from __future__ import annotations

from collections.abc import Generator, Iterator
from pathlib import Path

from core.driver import DriverAborted, DriverEvent, InstrumentState
from core.errors import InputError
from core.journal import JournalReader
from core.plan import Block, IndentResult, StepRecord


class ReplayDriver(InstrumentState):
    def __init__(self, journal: str | Path | JournalReader, speed: float | None = None) -> None:
        if speed is not None and speed <= 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        reader = journal if isinstance(journal, JournalReader) else JournalReader(journal)
        self.source = str(reader.path)
        self.profile = reader.profile
        self.speed = speed
        self._blocks = {rec.block.block_id: rec for rec in reader.blocks()}
        # each indent's steps: those committed with it (step ids up to the indent's last_step_id)
        cols, rows = reader.table("indents")
        ix = {name: i for i, name in enumerate(cols)}
        self._last_step: dict[tuple[int, int], int] = {
            (r[ix["block_id"]], r[ix["indent_index"]]): (r[ix["last_step_id"]] or 0) for r in rows
        }
        scols, srows = reader.table("steps")
        si = {name: i for i, name in enumerate(scols)}
        self._steps: list[tuple[int, StepRecord, float]] = [
            (
                r[si["step_id"]],
                StepRecord(r[si["category"]], r[si["seconds"]], r[si["block_id"]], r[si["indent_index"]]),
                r[si["t_end_s"]],
            )
            for r in sorted(srows, key=lambda r: r[si["step_id"]])
        ]
        if not isinstance(journal, JournalReader):
            reader.close()
        self._cursor = 0  # index into self._steps of the next step not yet played
        super().__init__()  # the recorded clock is the only clock: no physics clock to restore

    def _play(self, step: StepRecord, t_end_s: float) -> StepRecord:
        if self.speed is not None and step.seconds > 0:
            self._abort.wait(step.seconds / self.speed)
        self._clock_s = t_end_s
        if step.category == "comeback":
            self._open = False
        return step

    def _steps_until(self, last_step_id: int) -> Iterator[DriverEvent]:
        while self._cursor < len(self._steps) and self._steps[self._cursor][0] <= last_step_id:
            _, step, t_end = self._steps[self._cursor]
            self._cursor += 1
            yield self._play(step, t_end)

    def execute_block(self, block: Block, start_index: int = 0) -> Generator[DriverEvent, None, None]:
        if self._abort.is_set():
            raise DriverAborted("replay was aborted")
        rec = self._blocks.get(block.block_id)
        if rec is None:
            raise InputError(self.source, f"block {block.block_id} is not in the recorded run")
        if rec.block != block:
            raise InputError(self.source, f"block {block.block_id} differs from the recorded plan")
        results = {r.indent_index: r for r in rec.results}
        for i in range(start_index, block.n_indents):
            res: IndentResult | None = results.get(i)
            if res is None:
                raise InputError(
                    self.source, f"block {block.block_id} indent {i} was never measured in the recorded run"
                )
            yield from self._steps_until(self._last_step.get((block.block_id, i), 0))
            self._pos, self._open = (res.commanded_x_um, res.commanded_y_um), True
            self._clock_s = res.t_s
            yield res
            if self._abort.is_set():
                yield from self.end_program()
                raise DriverAborted(f"replay aborted after indent {i} of block {block.block_id}")

    def end_program(self) -> Iterator[StepRecord]:
        """Play the recorded steps that ended the program (the comeback), if any follow."""
        while self._cursor < len(self._steps):
            _, step, t_end = self._steps[self._cursor]
            if step.category != "comeback" or step.block_id >= 0:
                break
            self._cursor += 1
            yield self._play(step, t_end)
        self._open = False

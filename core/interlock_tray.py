"""The safety interlock over a tray: every block is checked by the interlock of the one sample it starts on.

Samples never overlap (core.sample.tray), so the sample under a block's first indent is the only one it may
be on; that sample's own :class:`~core.interlock.Interlock` then checks every indent (inside its outline,
clear of its exclusions and earlier indents, in its safe band, no hop without a reconfiguration), and
remembers the indents that ran. A block that starts on no sample is refused. The interlock reads only the
tray's geometry, never the planner's choice, so it stays independent of what it checks.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from core.interlock import Interlock
from core.plan import Block, IndentResult
from core.profile import load_profile
from core.sample.tray import Tray


class TrayInterlock(Interlock):
    def __init__(self, tray: Tray) -> None:
        self.tray = tray
        self.per_sample = {s.name: Interlock(s.placed, load_profile(s.placed.profile)) for s in tray.samples}
        first = tray.samples[0].placed
        super().__init__(first, load_profile(first.profile))

    def _owner(self, block: Block) -> Interlock | None:
        if not block.indents:
            return None
        spec = block.indents[0]
        entry = self.tray.sample_at(spec.x_um, spec.y_um)
        return None if entry is None else self.per_sample[entry.name]

    def check(self, block: Block, position_um: tuple[float, float], program_open: bool) -> str | None:
        if block.n_indents == 0:
            return f"block {block.block_id} has no indents"
        own = self._owner(block)
        if own is None:
            s = block.indents[0]
            return f"site 0 ({s.x_um:.1f}, {s.y_um:.1f}) µm is on no sample of the tray"
        if block.kind != "global":
            here = self.tray.sample_at(*position_um)
            if here is None or self.per_sample[here.name] is not own:
                return (
                    f"block {block.block_id} continues a program on {own.sample.name!r} but the tip is "
                    f"{'on ' + repr(here.name) if here else 'on no sample'}: a new sample needs a global block"
                )
        reason = own.check(block, position_um, program_open)
        return None if reason is None else f"{own.sample.name}: {reason}"

    def passed(self, block: Block, results: Sequence[IndentResult]) -> None:
        own = self._owner(block)
        if own is not None:
            own.passed(block, results)

    def restore(self, observed: Iterable[tuple[Block, Sequence[IndentResult]]]) -> None:
        for block, results in observed:
            self.passed(block, results)

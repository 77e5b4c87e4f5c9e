"""The KLA driver over a tray: the sample each block is on, what going to it costs, where the tip is.

One stage, one exchange folder and one InView serve every sample. Each sample is priced with the profile it is
planned with (``core.run.tray.tray_profiles``), and the first block on a sample after a block on another one
pays the sample change (``core.sample_change``), as the planner priced it and the simulated tray charges it.

InView's test methods stay one set, the profile's hold table (``InViewSettings.method_for``): a method file
per sample is no convention of InView's file exchange we know of (a lab loads a method per array, by name),
so a tray whose samples' profiles disagree on the ``[inview]`` section is refused rather than guessed.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from core.errors import InputError
from core.plan import Block, StepRecord
from core.profile import InstrumentProfile
from core.sample.tray import Tray
from core.sample_change import change_steps, tip_sample


@dataclass(frozen=True)
class KlaTray:
    """The tray as the KLA driver needs it: where each sample is and the profile it is priced with."""

    tray: Tray
    profiles: Mapping[str, InstrumentProfile]

    def __post_init__(self) -> None:
        first = self.tray.libraries[0]
        for s in self.tray.samples:
            if self.profiles[s.name].inview != self.profiles[first.name].inview:
                raise InputError(
                    f"tray sample {s.name!r}",
                    f"its profile ({s.placed.profile}) has other [inview] settings than {first.name}'s "
                    f"({first.placed.profile}): one InView runs the whole tray with one set of methods and one "
                    "array convention; give the samples one profile",
                )

    @property
    def first_profile(self) -> InstrumentProfile:
        return self.profiles[self.tray.libraries[0].name]

    def sample_of(self, block: Block) -> str:
        """The sample under the block's first indent (the interlock passed only blocks inside one)."""
        first = block.indents[0]
        entry = self.tray.sample_at(first.x_um, first.y_um)
        if entry is None:  # the interlock refuses such a block first; an instrument would find no surface
            raise ValueError(f"block {block.block_id} starts on no sample of the tray")
        return entry.name

    def change(self, block: Block, on: str | None) -> list[StepRecord]:
        """The sample change the block pays when the tip was last on another sample (none on the same one,
        and none for the run's first block)."""
        name = self.sample_of(block)
        if on is None or on == name:
            return []
        return change_steps(self.profiles[name], block.block_id)

    def on_after_restore(self, clock_s: float, position_um: tuple[float, float]) -> str | None:
        return tip_sample(self.tray, clock_s, position_um)

"""What going to another sample of a tray costs, beyond the global block that starts there.

A global block already pays its program's setup, lift, the move (lifted), one engage and one drift settle
(core.cost). Moving to *another* sample adds what a new surface and a new mount ask for, priced from the
instrument profile so the planner's price and the simulated instrument's clock agree:

- ``surface find``: the approach starts from the travel height over a surface the instrument has not touched
  yet (its height known only from the sample's corners), one more approach at the profile's engage time
  (``engage_s``). Assumption to check on the instrument (the paper prices one engage per block).
- ``thermal settle``: a different mount on a different holder settles anew; one more drift settle at the
  profile's ``drift_settle_s`` (SPEC §3 calls the settle "variable and bounded"). Assumption to check.

The long stage travel itself is the profile's move model (linear above 500 µm; fitted on moves of a few mm,
so a move of centimetres is an extrapolation, small beside the settle either way).
"""

from __future__ import annotations

from core.plan import StepRecord
from core.profile import InstrumentProfile
from core.sample.tray import Tray


def change_steps(profile: InstrumentProfile, block_id: int = -1) -> list[StepRecord]:
    """The extra steps of the first block on a sample after a block on another one (in the ledger's own
    categories: a surface find is an engage, a thermal settle a drift settle)."""
    return [
        StepRecord("engage", profile.engage_s, block_id, -1),
        StepRecord("drift", profile.drift_settle_s, block_id, -1),
    ]


def change_s(profile: InstrumentProfile) -> float:
    return sum(s.seconds for s in change_steps(profile))


def travel_s(profile: InstrumentProfile, frm_um: tuple[float, float], to_um: tuple[float, float]) -> float:
    """The stage move between two points, lifted (t(|dx|) + t(|dy|))."""
    return float(profile.move_s(abs(to_um[0] - frm_um[0]), abs(to_um[1] - frm_um[1])))


def tip_sample(tray: Tray, clock_s: float, position_um: tuple[float, float]) -> str | None:
    """The sample the tip is on when an instrument is put back where a journal left it: the one under its
    last position; none while nothing has run (clock 0: the first block changes onto no sample, as planned).
    """
    if clock_s <= 0:
        return None
    here = tray.sample_at(*position_um)
    return None if here is None else here.name

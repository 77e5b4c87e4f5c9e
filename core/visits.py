"""The simulated operator: when each block is loaded on the wall clock, and how many visits that takes.

A headless run's clock counts instrument time only; a lab judges a run by the calendar and by how often
someone must come to the instrument. This sink follows a run's events: every block that needs a person
(an array to load) is a request, answered when :class:`core.operator.OperatorAvailability` says (within
the response time during hours, not at all outside them); the instrument idles until then. A plan that is
known in full before the run (the grid baseline) is loaded once, and the later arrays of a stretch were
loaded with its first.

The planner asks :meth:`SimulatedOperator.unattended` how long the next load will run before anyone
comes again, to plan a stretch that fills it (and when it must not end).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import datetime, timedelta

from core.operator import LoadWindow, OperatorAvailability, wall_seconds
from core.plan import STRETCH_CONTINUES, Decision
from core.run.events import BlockStarted, Decided, Observed, RunEvent

# a plan fixed before the run is one array list, loaded once (the grid baseline)
LOADED_ONCE_PHASES: frozenset[str] = frozenset({"grid"})


def unattended_after(availability: OperatorAvailability, now: datetime) -> LoadWindow:
    """The calendar's window for a load answering a request made at ``now``: it runs until the operator
    comes by again, the next routine visit during hours (``visit_every_s`` after the load), or, when they
    leave (or are away) before that visit can be answered, until they answer again after the absence (inf:
    nobody ever comes); and it must not end between the day's last answerable moment and that answer. An
    operator who has said they are away until a time (``away_until``) loads this block as they leave."""
    if availability.away_until is not None and now < availability.away_until:
        back = availability.answers_at(now)
        return LoadWindow(math.inf if back is None else wall_seconds(now, back))
    loaded = availability.answers_at(now)
    if loaded is None:
        return LoadWindow(math.inf)
    leave = availability.hours.next_departure(loaded)
    if leave is None:
        return LoadWindow(availability.visit_every_s)
    last = leave - timedelta(seconds=availability.response_s)  # a later request waits for the next morning
    back = availability.answers_at(leave)
    next_answer_s = math.inf if back is None else wall_seconds(loaded, back)
    routine = loaded + timedelta(seconds=availability.visit_every_s)
    # the routine visit loads the next arrays only if the request it answers is answered before they leave
    fill_s = availability.visit_every_s if routine <= last else next_answer_s
    return LoadWindow(fill_s, wall_seconds(loaded, last), next_answer_s)


@dataclass(frozen=True)
class CalendarPoint:
    """After a block: instrument time, wall clock since the start, and operator visits so far."""

    t_s: float
    wall_s: float
    visits: int


@dataclass
class SimulatedOperator:
    """A sink that puts a run on the calendar (see the module docstring)."""

    availability: OperatorAvailability
    start: datetime
    waited_s: float = 0.0  # wall seconds the instrument stood waiting for the operator
    visits: int = 0
    points: list[CalendarPoint] = field(default_factory=list)
    _waiting: dict[int, Decision] = field(default_factory=dict, repr=False)

    def now(self, t_s: float) -> datetime:
        return self.start + timedelta(seconds=t_s + self.waited_s)

    def wall_s(self, t_s: float) -> float:
        return t_s + self.waited_s

    def wall_at(self, t_s: float) -> float | None:
        """Wall seconds at instrument time ``t_s`` of a block already observed (None: none yet)."""
        before = [p for p in self.points if p.t_s <= t_s + 1e-6]
        if not before:
            return None
        return t_s + (before[-1].wall_s - before[-1].t_s)

    def visits_at(self, t_s: float) -> int:
        return max((p.visits for p in self.points if p.t_s <= t_s + 1e-6), default=0)

    def load(self, t_s: float) -> None:
        """A block needs a person at instrument time ``t_s``: the instrument waits for the answer."""
        self.visits += 1
        if math.isinf(self.waited_s):
            return
        now = self.now(t_s)
        answer = self.availability.answers_at(now)
        self.waited_s = math.inf if answer is None else self.waited_s + (answer - now).total_seconds()

    def unattended(self, t_s: float) -> LoadWindow:
        """:func:`unattended_after` a request made at instrument time ``t_s``."""
        if math.isinf(self.waited_s):
            return LoadWindow(math.inf)
        return unattended_after(self.availability, self.now(t_s))

    def emit(self, event: RunEvent) -> None:
        if isinstance(event, Decided):
            if event.plan is not None:
                self._starts(event.decision, event.t_s)
            else:
                self._waiting[event.decision_id] = event.decision
        elif isinstance(event, BlockStarted):
            decision = self._waiting.pop(event.decision_id, None)
            if decision is not None:
                self._starts(decision, event.t_s)
        elif isinstance(event, Observed):
            self.points.append(CalendarPoint(event.t_s, self.wall_s(event.t_s), self.visits))

    def _starts(self, decision: Decision, t_s: float) -> None:
        if decision.phase == STRETCH_CONTINUES and self.visits:
            return
        if decision.phase in LOADED_ONCE_PHASES and self.visits:
            return
        self.load(t_s)


@dataclass(frozen=True)
class OperatorCalendar:
    """A simulated run's calendar: who answers when, and the wall-clock moment the run starts."""

    availability: OperatorAvailability
    start: datetime

    def operator(self) -> SimulatedOperator:
        return SimulatedOperator(self.availability, self.start)

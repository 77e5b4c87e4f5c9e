"""When a person can come to the instrument: working hours, response time, visits and ad-hoc absences.

A KLA block needs a person to load, start and export it, so a run's calendar, not only its instrument time,
decides how soon a map is done. The planner asks this module how long nobody will be there (to plan a
stretch that fills the absence); the bench's simulated operator answers requests by the same rules.

Times are naive local wall-clock datetimes (the lab's clock), with minute resolution for the hours.
"""

from __future__ import annotations

import math
import re
from bisect import bisect_right
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timedelta

from core.errors import InputError

WEEKDAYS: tuple[str, ...] = ("Mon", "Tue", "Wed", "Thu", "Fri", "Sat", "Sun")
MIN_PER_DAY = 24 * 60
MIN_PER_WEEK = 7 * MIN_PER_DAY
# a Monday, for schedules given by weekday only ("Mon 09:00"): the bench's calendar starts in this week
REFERENCE_MONDAY = datetime(2024, 1, 1)

_DAY = {d.lower(): i for i, d in enumerate(WEEKDAYS)}
_SHIFT_RE = re.compile(
    r"^\s*(?P<days>[A-Za-z,\s-]+?)\s+(?P<start>\d{1,2}:\d{2})\s*-\s*(?P<end>\d{1,2}:\d{2})\s*$"
)
_TIME_RE = re.compile(r"^(\d{1,2}):(\d{2})$")


def _minutes(text: str, source: str, *, allow_24: bool) -> int:
    m = _TIME_RE.match(text.strip())
    if m is None:
        raise InputError(source, f"{text!r} is not a time: expected HH:MM")
    h, mi = int(m.group(1)), int(m.group(2))
    if mi >= 60 or h > 24 or (h == 24 and (mi != 0 or not allow_24)):
        raise InputError(
            source, f"{text!r} is not a time of day (00:00 to {'24:00' if allow_24 else '23:59'})"
        )
    return h * 60 + mi


def _days(text: str, source: str) -> list[int]:
    out: list[int] = []
    for part in (p.strip() for p in text.split(",")):
        if not part:
            raise InputError(source, f"{text!r}: an empty day in the list")
        ends = [e.strip().lower()[:3] for e in part.split("-")]
        if len(ends) > 2 or any(e not in _DAY for e in ends):
            raise InputError(
                source, f"{part!r} is not a day or a day range such as Mon-Fri (days: {', '.join(WEEKDAYS)})"
            )
        a, b = _DAY[ends[0]], _DAY[ends[-1]]
        out.extend((a + k) % 7 for k in range((b - a) % 7 + 1))
    return out


def _merge(intervals: list[tuple[int, int]]) -> tuple[tuple[int, int], ...]:
    """Sorted, merged [start, end) minute-of-week intervals; those that cross Sunday midnight are split."""
    flat: list[tuple[int, int]] = []
    for a, b in intervals:
        if b <= MIN_PER_WEEK:
            flat.append((a, b))
        else:
            flat.extend([(a, MIN_PER_WEEK), (0, b - MIN_PER_WEEK)])
    flat.sort()
    merged: list[tuple[int, int]] = []
    for a, b in flat:
        if merged and a <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], b))
        else:
            merged.append((a, b))
    return tuple(merged)


def _minute_of_week(t: datetime) -> float:
    return t.weekday() * MIN_PER_DAY + t.hour * 60 + t.minute + (t.second + t.microsecond / 1e6) / 60.0


@dataclass(frozen=True)
class OperatorHours:
    """The weekly hours someone is at or near the instrument, as minute-of-week intervals.

    Written like ``"Mon-Fri 08:30-18:00"``; several shifts are separated by ``;``
    (``"Mon-Fri 08:30-18:00; Sat 10:00-12:00"``), days may be listed (``"Mon,Wed,Fri 09:00-17:00"``), a
    shift may end past midnight (``"Fri 22:00-02:00"`` ends on Saturday), and ``"always"`` and ``"never"``
    mean what they say (``"never"``: every block is planned for nobody).
    """

    text: str
    intervals: tuple[tuple[int, int], ...] = field(repr=False)

    @classmethod
    def parse(cls, text: str, source: str = "operator.hours") -> OperatorHours:
        s = text.strip()
        if s.lower() in ("always", "24/7"):
            return cls(s, ((0, MIN_PER_WEEK),))
        if s.lower() == "never":
            return cls(s, ())
        raw: list[tuple[int, int]] = []
        for shift in (p for p in s.split(";")):
            if not shift.strip():
                raise InputError(source, f"{text!r}: an empty shift between ';'")
            m = _SHIFT_RE.match(shift)
            if m is None:
                raise InputError(
                    source,
                    f"{shift.strip()!r} is not a shift: expected days and hours such as 'Mon-Fri 08:30-18:00' "
                    "(or 'always', 'never')",
                )
            start = _minutes(m.group("start"), source, allow_24=False)
            end = _minutes(m.group("end"), source, allow_24=True)
            if end == start:
                raise InputError(
                    source, f"{shift.strip()!r} has no length (start and end are both {m.group('start')})"
                )
            length = end - start if end > start else end + MIN_PER_DAY - start
            for d in _days(m.group("days"), source):
                a = d * MIN_PER_DAY + start
                raw.append((a, a + length))
        return cls(s, _merge(raw))

    @property
    def always(self) -> bool:
        return self.intervals == ((0, MIN_PER_WEEK),)

    @property
    def never(self) -> bool:
        return not self.intervals

    def _find(self, mow: float) -> int:
        """Index of the interval that starts at or before ``mow`` (-1: none)."""
        return bisect_right([a for a, _ in self.intervals], mow) - 1

    def present(self, t: datetime) -> bool:
        mow = _minute_of_week(t)
        i = self._find(mow)
        return i >= 0 and mow < self.intervals[i][1]

    def next_arrival(self, t: datetime) -> datetime | None:
        """The first moment at or after ``t`` when someone is there (``t`` itself when present); None: never."""
        if self.never:
            return None
        if self.present(t):
            return t
        mow = _minute_of_week(t)
        later = [a for a, _ in self.intervals if a > mow]
        wait_min = (later[0] - mow) if later else (MIN_PER_WEEK - mow + self.intervals[0][0])
        return t + timedelta(minutes=wait_min)

    def next_departure(self, t: datetime) -> datetime | None:
        """When the presence that covers ``t`` ends (``t`` itself when nobody is there); None: never ends."""
        if self.always:
            return None
        if not self.present(t):
            return t
        mow = _minute_of_week(t)
        i = self._find(mow)
        end = float(self.intervals[i][1])
        # presence that runs through Sunday midnight into Monday continues
        if end == MIN_PER_WEEK and self.intervals[0][0] == 0:
            end += self.intervals[0][1]
        return t + timedelta(minutes=end - mow)


@dataclass(frozen=True)
class LoadWindow:
    """What the calendar asks of one load, in seconds from when it is loaded.

    It should run about ``fill_s`` (until someone comes again). And it must not end between
    ``last_answer_s``, the last moment a request is still answered before everybody leaves, and
    ``next_answer_s``, when one is answered after the absence: nobody would load the next arrays, so the
    instrument would stand idle the whole absence (inf: no such absence ahead).
    """

    fill_s: float
    last_answer_s: float = math.inf
    next_answer_s: float = math.inf


class Attendance:
    """When anyone will next come to the instrument, as the planner asks it before it designs a load.

    One object shared by the campaign (which reads it) and the engine (which follows the operator's word: an
    away-until, the run file's hours on the local clock); the campaign is never reconfigured for it. Without
    a window the run is planned as if someone were always there."""

    def __init__(self, window: Callable[[float], LoadWindow | None] | None = None) -> None:
        self._window = window

    @property
    def known(self) -> bool:
        """The run knows when its operator is there (a calendar, an [operator] section, an away-until)."""
        return self._window is not None

    def window(self, clock_s: float) -> LoadWindow | None:
        """The next load's window for a request at instrument time ``clock_s`` (None: always attended)."""
        return None if self._window is None else self._window(clock_s)

    def follow(self, window: Callable[[float], LoadWindow | None] | None) -> None:
        """The operator's availability changed: later loads are planned by ``window``."""
        self._window = window


@dataclass(frozen=True)
class OperatorAvailability:
    """Who answers, and when: the weekly hours, the response time, routine visits and an ad-hoc absence."""

    hours: OperatorHours
    response_s: float = 600.0
    visit_every_s: float = 7200.0
    away_until: datetime | None = None

    def __post_init__(self) -> None:
        if not 0 <= self.response_s <= 24 * 3600:
            raise InputError(
                "operator.response_min", f"{self.response_s / 60:g} min is not allowed: 0 to 1440"
            )
        if not 0 < self.visit_every_s <= 7 * 24 * 3600:
            raise InputError(
                "operator.visit_every_min", f"{self.visit_every_s / 60:g} min is not allowed: > 0, ≤ one week"
            )

    def present(self, t: datetime) -> bool:
        if self.away_until is not None and t < self.away_until:
            return False
        return self.hours.present(t)

    def next_arrival(self, t: datetime) -> datetime | None:
        start = t if self.away_until is None or t >= self.away_until else self.away_until
        return self.hours.next_arrival(start)

    def answers_at(self, t: datetime) -> datetime | None:
        """When a request made at ``t`` (an alert, a block to load) is answered; None: nobody ever comes.

        During hours the operator answers within the response time; outside them, the response time after
        they arrive, but never later than the presence allows (a request 5 min before they leave is answered
        before they leave when the response fits, else at their next arrival).
        """
        first = arrive = self.next_arrival(t)
        if first is None:
            return None
        for _ in range(len(self.hours.intervals) + 1):  # every presence of a week, tried once
            assert arrive is not None
            answer = arrive + timedelta(seconds=self.response_s)
            leave = self.hours.next_departure(arrive)
            if leave is None or answer <= leave:
                return answer
            arrive = self.next_arrival(leave)
        # every presence is shorter than the response: they answer as soon as they can
        return first + timedelta(seconds=self.response_s)

    def answer_delay_s(self, t: datetime) -> float:
        """How long after ``t`` a wait for the operator (a KLA ticket's deadline) starts counting: 0 when a
        request made at ``t`` is answered within the response time (as during the hours: the deadline's
        margin covers the response), else until they answer after the absence (0 when nobody ever comes)."""
        wait_s = self.unattended_s(t)
        return 0.0 if math.isinf(wait_s) or wait_s <= self.response_s else wait_s

    def unattended_s(self, t: datetime) -> float:
        """Seconds from ``t`` until a request made at ``t`` is answered (inf: nobody ever comes)."""
        answer = self.answers_at(t)
        return float("inf") if answer is None else wall_seconds(t, answer)

    def absence_ahead(self, t: datetime) -> tuple[datetime, datetime | None] | None:
        """The next stretch with nobody there, as (from, until); until None: nobody comes back. None: no absence."""
        if not self.present(t):
            return (t, self.next_arrival(t))
        leave = self.hours.next_departure(t)
        if leave is None:
            return None
        return (leave, self.next_arrival(leave))


def wall_seconds(a: datetime, b: datetime) -> float:
    """``b - a`` in real seconds. Hours are local clock readings (naive datetimes); read with the local time
    zone's rules, a night across a daylight-saving change is an hour shorter or longer than its reading (the
    engine gave a ticket written before a spring-forward an hour too long to wait)."""
    return b.timestamp() - a.timestamp()


def parse_when(text: str, now: datetime, source: str) -> datetime:
    """A wall-clock moment as an operator types it: ``08:00`` (the next one), ``Mon 09:00``, or ISO 8601."""
    s = text.strip()
    m = re.match(r"^(?:(?P<day>[A-Za-z]{3})[a-z]*\s+)?(?P<time>\d{1,2}:\d{2})$", s)
    if m is not None:
        minute = _minutes(m.group("time"), source, allow_24=False)
        base = now.replace(hour=0, minute=0, second=0, microsecond=0) + timedelta(minutes=minute)
        if m.group("day") is not None:
            day = m.group("day").lower()
            if day not in _DAY:
                raise InputError(source, f"{text!r}: {m.group('day')!r} is not a day ({', '.join(WEEKDAYS)})")
            base += timedelta(days=(_DAY[day] - now.weekday()) % 7)
            return base if base > now else base + timedelta(days=7)
        return base if base > now else base + timedelta(days=1)
    try:
        return datetime.fromisoformat(s)
    except ValueError:
        raise InputError(
            source,
            f"{text!r} is not a time: expected HH:MM, a day and HH:MM ('Mon 09:00') or an ISO date-time",
        ) from None


def parse_start(text: str, source: str = "--start") -> datetime:
    """A simulated run's start: ``"Mon 09:00"`` lands in the reference week; ISO 8601 is taken as it is."""
    return parse_when(text, REFERENCE_MONDAY - timedelta(microseconds=1), source)

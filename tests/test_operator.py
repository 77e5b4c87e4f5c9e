"""The operator's calendar: hours, arrivals, departures and answers, against a minute-by-minute reading."""

from __future__ import annotations

from datetime import datetime, timedelta

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from core.errors import InputError
from core.operator import (
    REFERENCE_MONDAY,
    WEEKDAYS,
    OperatorAvailability,
    OperatorHours,
    parse_start,
    parse_when,
)


def _brute_present(shifts: list[tuple[list[int], int, int]], t: datetime) -> bool:
    """Present at t by the plain reading of the shifts (days, start and end minute; end < start: past midnight)."""
    day, minute = t.weekday(), t.hour * 60 + t.minute + t.second / 60
    for days, start, end in shifts:
        for d in days:
            if end > start and d == day and start <= minute < end:
                return True
            if end <= start and ((d == day and minute >= start) or ((d + 1) % 7 == day and minute < end)):
                return True
    return False


@st.composite
def shift_specs(draw: st.DrawFn) -> tuple[str, list[tuple[list[int], int, int]]]:
    parts, shifts = [], []
    for _ in range(draw(st.integers(1, 3))):
        a = draw(st.integers(0, 6))
        n = draw(st.integers(0, 6))
        days = [(a + k) % 7 for k in range(n + 1)]
        start = draw(st.integers(0, 23 * 60 + 59))
        end = draw(st.integers(0, 24 * 60).filter(lambda e, s=start: e != s))
        day_text = WEEKDAYS[a] if n == 0 else f"{WEEKDAYS[a]}-{WEEKDAYS[(a + n) % 7]}"
        parts.append(f"{day_text} {start // 60:02d}:{start % 60:02d}-{end // 60:02d}:{end % 60:02d}")
        shifts.append((days, start, end % (24 * 60) if end == 24 * 60 and start == 0 else end))
    return "; ".join(parts), shifts


moments = st.integers(0, 14 * 24 * 60 - 1).map(lambda m: REFERENCE_MONDAY + timedelta(minutes=m, seconds=30))


@settings(max_examples=300, deadline=None)
@given(spec=shift_specs(), t=moments)
def test_presence_arrival_and_departure_agree_with_a_minute_by_minute_reading(spec, t) -> None:
    text, shifts = spec
    hours = OperatorHours.parse(text)

    def brute(x: datetime) -> bool:
        # "00:00-24:00" reads as the whole day in the plain reading too
        return _brute_present([(d, s, 24 * 60 if (s, e) == (0, 0) else e) for d, s, e in shifts], x)

    assert hours.present(t) == brute(t)
    arrive = hours.next_arrival(t)
    assert arrive is not None and arrive >= t and hours.present(arrive)
    # nobody there at any minute between t and the arrival
    probe = t
    while probe + timedelta(minutes=1) < arrive:
        probe += timedelta(minutes=1)
        assert not brute(probe)
    leave = hours.next_departure(t)
    if leave is not None:
        assert leave >= t and not hours.present(leave)
        step = max(timedelta(minutes=1), (leave - t) / 500)
        probe = t
        while probe + step < leave:
            probe += step
            if hours.present(t):
                assert brute(probe)


@settings(max_examples=200, deadline=None)
@given(spec=shift_specs(), t=moments, response_min=st.integers(0, 120))
def test_a_request_is_answered_after_the_response_time_and_while_someone_is_there(
    spec, t, response_min
) -> None:
    hours = OperatorHours.parse(spec[0])
    avail = OperatorAvailability(hours, response_s=response_min * 60.0)
    answer = avail.answers_at(t)
    assert answer is not None
    assert answer >= t + timedelta(minutes=response_min)
    assert avail.unattended_s(t) == (answer - t).total_seconds()


def test_the_issue_s_working_week() -> None:
    avail = OperatorAvailability(OperatorHours.parse("Mon-Fri 08:30-18:00"), response_s=600)
    friday_5pm = datetime(2024, 1, 5, 17, 0)
    assert avail.absence_ahead(friday_5pm) == (datetime(2024, 1, 5, 18, 0), datetime(2024, 1, 8, 8, 30))
    # a request at 17:55 does not fit before 18:00: answered Monday 08:40
    assert avail.answers_at(datetime(2024, 1, 5, 17, 55)) == datetime(2024, 1, 8, 8, 40)
    assert avail.answers_at(datetime(2024, 1, 3, 10, 0)) == datetime(2024, 1, 3, 10, 10)
    # an ad-hoc absence
    away = OperatorAvailability(avail.hours, response_s=600, away_until=datetime(2024, 1, 4, 8, 0))
    assert not away.present(datetime(2024, 1, 3, 10, 0))
    assert away.answers_at(datetime(2024, 1, 3, 10, 0)) == datetime(2024, 1, 4, 8, 40)


def test_always_never_and_past_midnight() -> None:
    assert OperatorHours.parse("always").next_departure(REFERENCE_MONDAY) is None
    never = OperatorAvailability(OperatorHours.parse("never"))
    assert never.answers_at(REFERENCE_MONDAY) is None and never.unattended_s(REFERENCE_MONDAY) == float("inf")
    night = OperatorHours.parse("Sun 22:00-02:00")
    assert night.present(datetime(2024, 1, 8, 1, 0))  # Monday 01:00 of the next week
    assert night.next_departure(datetime(2024, 1, 7, 23, 0)) == datetime(2024, 1, 8, 2, 0)


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("Mon-Fri", "not a shift"),
        ("Mon-Fri 8:30-25:00", "not a time of day"),
        ("Mon-Fri 08:30-08:30", "no length"),
        ("Mo-Fry 08:30-18:00", "not a day"),
        ("Mon-Fri 08:30-18:00;", "empty shift"),
        ("Mon-Fri 08:61-18:00", "not a time of day"),
    ],
)
def test_bad_hours_are_refused_in_one_line_naming_the_field(text: str, words: str) -> None:
    with pytest.raises(InputError) as info:
        OperatorHours.parse(text)
    assert info.value.source == "operator.hours" and words in info.value.problem
    assert "\n" not in str(info.value)


def test_moments_as_an_operator_types_them() -> None:
    now = datetime(2024, 1, 3, 22, 0)  # Wednesday night
    assert parse_when("08:00", now, "away-until") == datetime(2024, 1, 4, 8, 0)
    assert parse_when("Mon 09:00", now, "away-until") == datetime(2024, 1, 8, 9, 0)
    assert parse_when("2024-01-05T12:00", now, "away-until") == datetime(2024, 1, 5, 12, 0)
    assert parse_start("Mon 09:00") == datetime(2024, 1, 1, 9, 0)
    assert parse_start("Sun 09:00") == datetime(2024, 1, 7, 9, 0)
    with pytest.raises(InputError, match="away-until"):
        parse_when("tomorrow", now, "away-until")
    with pytest.raises(InputError, match="response_min"):
        OperatorAvailability(OperatorHours.parse("always"), response_s=-1)

"""The run's state machine: one table says where each trigger leads and which commands each state takes."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from core.run.machine import (
    ALLOWED,
    TERMINAL,
    TRANSITIONS,
    CommandKind,
    EngineState,
    Machine,
    TransitionError,
    Trigger,
    allowed,
    refusal,
)


def test_every_state_has_a_row_and_terminal_states_take_nothing() -> None:
    assert set(TRANSITIONS) == set(EngineState) == set(ALLOWED)
    for state in TERMINAL:
        assert not TRANSITIONS[state] and not ALLOWED[state]
    # every live state can fail and can be stopped; a paused run resumes where it was
    for state in set(EngineState) - TERMINAL - {EngineState.IDLE}:
        assert TRANSITIONS[state][Trigger.FAIL] is EngineState.FAILED
        assert Trigger.STOP in TRANSITIONS[state]
        assert CommandKind.ABORT in ALLOWED[state] or state is EngineState.STOPPING


@given(st.lists(st.sampled_from(list(Trigger)), max_size=40))
def test_random_triggers_follow_the_table_and_resume_returns_to_the_paused_state(
    triggers: list[Trigger],
) -> None:
    m = Machine()
    for trigger in triggers:
        before = m.state
        if not m.can(trigger):
            with pytest.raises(TransitionError):
                m.fire(trigger)
            assert m.state is before
            continue
        after = m.fire(trigger)
        if trigger is Trigger.RESUME:
            assert before is EngineState.PAUSED and after is not EngineState.PAUSED
            assert Trigger.PAUSE in TRANSITIONS[after]  # back where the pause found it
        elif trigger is Trigger.PAUSE:
            assert after is EngineState.PAUSED and m.paused_from is before
        else:
            assert TRANSITIONS[before][trigger] is after
        assert m.state is after


def test_approval_commands_only_while_a_decision_waits() -> None:
    for state in EngineState:
        assert allowed(state, CommandKind.APPROVE) == (state is EngineState.AWAITING_APPROVAL)
        assert allowed(state, CommandKind.RESUME) == (state is EngineState.PAUSED)
    assert refusal(EngineState.RUNNING, CommandKind.APPROVE) == "nothing is waiting for approval"
    assert refusal(EngineState.PAUSED, CommandKind.VETO) == "the run is paused: resume it first"
    assert refusal(EngineState.RUNNING, CommandKind.RESUME) == "not paused"
    assert refusal(EngineState.PAUSED, CommandKind.PAUSE) == "already paused"
    assert "STOPPING" in refusal(EngineState.STOPPING, CommandKind.ADJUST)

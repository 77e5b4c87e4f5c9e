"""The run's state machine: its states, the one transition table, and which commands each state takes.

The engine's state is only ever changed through :meth:`Machine.fire`, and the console asks
:func:`allowed` which keys to offer, so the two cannot disagree about what a state means.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum


class EngineState(StrEnum):
    IDLE = "idle"
    RUNNING = "running"
    PAUSED = "paused"
    AWAITING_APPROVAL = "awaiting-approval"
    WAITING_FOR_INSTRUMENT = "waiting-for-instrument"  # a ticket is out: the operator runs the array
    STOPPING = "stopping"
    STOPPED = "stopped"
    FAILED = "failed"

    @property
    def label(self) -> str:
        """What the status bar shows: the state in capitals."""
        return self.value.replace("-", " ").upper()


class CommandKind(StrEnum):
    PAUSE = "pause"
    RESUME = "resume"
    APPROVE = "approve"
    VETO = "veto"
    ADJUST = "adjust"
    STEP = "step"  # in step mode: run one block
    STOP_AFTER_BLOCK = "stop-after-block"
    ABORT = "abort"
    CONFIRM = "confirm"  # the array started: payload token
    REPORT = "report"  # payload kind (aborted | surface-not-found), token
    SKIP = "skip"  # payload site (1-based, as in the sites file)
    AWAY_UNTIL = "away-until"  # payload until (ISO local time): nobody answers before it


class Trigger(StrEnum):
    """What happened, as the engine tells the machine."""

    START = "start"  # the engine process began (or resumed) the run
    ASK = "ask"  # a decision waits for the operator
    GO = "go"  # the run proceeds: a decision was released, an instrument wait ended
    WAIT_INSTRUMENT = "wait-instrument"  # the driver waits for the instrument (a KLA ticket is out)
    PAUSE = "pause"
    RESUME = "resume"
    STOP = "stop"  # finished, stopped after a block, aborted: lift and end the program
    STOPPED = "stopped"  # the program ended, the run is over
    FAIL = "fail"


# when a block waits for the operator (Trigger.ASK): auto only for one the interlock refuses, supervised also
# at a global jump or a collapse alarm, step before every block (the engine's _approval_reason)
SUPERVISION_MODES: tuple[str, ...] = ("auto", "supervised", "step")

S, T = EngineState, Trigger
RETURN = "return"  # RESUME's target: the state the run was paused from

# the one transition table: state -> trigger -> next state
TRANSITIONS: Mapping[EngineState, Mapping[Trigger, EngineState | str]] = {
    S.IDLE: {T.START: S.RUNNING, T.FAIL: S.FAILED},
    S.RUNNING: {
        T.ASK: S.AWAITING_APPROVAL,
        T.GO: S.RUNNING,
        T.WAIT_INSTRUMENT: S.WAITING_FOR_INSTRUMENT,
        T.PAUSE: S.PAUSED,
        T.STOP: S.STOPPING,
        T.FAIL: S.FAILED,
    },
    S.AWAITING_APPROVAL: {
        T.ASK: S.AWAITING_APPROVAL,  # a veto brought the next proposal, which waits too
        T.GO: S.RUNNING,
        T.PAUSE: S.PAUSED,
        T.STOP: S.STOPPING,
        T.FAIL: S.FAILED,
    },
    S.WAITING_FOR_INSTRUMENT: {
        T.WAIT_INSTRUMENT: S.WAITING_FOR_INSTRUMENT,
        T.GO: S.RUNNING,
        T.PAUSE: S.PAUSED,
        T.STOP: S.STOPPING,
        T.FAIL: S.FAILED,
    },
    S.PAUSED: {T.RESUME: RETURN, T.STOP: S.STOPPING, T.FAIL: S.FAILED},
    S.STOPPING: {T.STOP: S.STOPPING, T.STOPPED: S.STOPPED, T.FAIL: S.FAILED},
    S.STOPPED: {},
    S.FAILED: {},
}

C = CommandKind
_EVERYWHERE_LIVE = frozenset({C.ADJUST, C.ABORT, C.AWAY_UNTIL})
_INSTRUMENT = frozenset({C.CONFIRM, C.REPORT, C.SKIP})
# which operator commands each state takes (the engine rejects the rest, the console hides their keys)
ALLOWED: Mapping[EngineState, frozenset[CommandKind]] = {
    S.IDLE: frozenset(),
    S.RUNNING: _EVERYWHERE_LIVE | {C.PAUSE, C.STOP_AFTER_BLOCK},
    S.AWAITING_APPROVAL: _EVERYWHERE_LIVE | {C.PAUSE, C.STOP_AFTER_BLOCK, C.APPROVE, C.VETO, C.STEP},
    S.WAITING_FOR_INSTRUMENT: _EVERYWHERE_LIVE | _INSTRUMENT | {C.PAUSE, C.STOP_AFTER_BLOCK},
    S.PAUSED: _EVERYWHERE_LIVE | _INSTRUMENT | {C.RESUME, C.STOP_AFTER_BLOCK},
    S.STOPPING: frozenset(),
    S.STOPPED: frozenset(),
    S.FAILED: frozenset(),
}
TERMINAL: frozenset[EngineState] = frozenset({S.STOPPED, S.FAILED})


def allowed(state: EngineState, kind: CommandKind) -> bool:
    return kind in ALLOWED[state]


def refusal(state: EngineState, kind: CommandKind) -> str:
    """Why ``kind`` is refused in ``state``, in the operator's words."""
    if kind in (C.APPROVE, C.VETO, C.STEP):
        if state is S.PAUSED:
            return "the run is paused: resume it first"
        return "nothing is waiting for approval"
    if kind is C.RESUME:
        return "not paused"
    if kind is C.PAUSE and state is S.PAUSED:
        return "already paused"
    if kind in _INSTRUMENT:
        return "nothing is waiting for the instrument"
    return f"{kind.value} is not taken while the run is {state.label}"


class TransitionError(RuntimeError):
    """The engine fired a trigger its state has no transition for: a bug, never an operator's doing."""


@dataclass
class Machine:
    """The current state, changed only by :meth:`fire` along :data:`TRANSITIONS`."""

    state: EngineState = EngineState.IDLE
    paused_from: EngineState | None = field(default=None)

    def can(self, trigger: Trigger) -> bool:
        return trigger in TRANSITIONS[self.state]

    def fire(self, trigger: Trigger) -> EngineState:
        """Move along the table; returns the new state (the same one for a self-loop)."""
        target = TRANSITIONS[self.state].get(trigger)
        if target is None:
            raise TransitionError(f"no transition from {self.state.value} on {trigger.value}")
        if target == RETURN:
            assert self.paused_from is not None
            target, self.paused_from = self.paused_from, None
        elif trigger is T.PAUSE:
            self.paused_from = self.state
        assert isinstance(target, EngineState)
        self.state = target
        return target

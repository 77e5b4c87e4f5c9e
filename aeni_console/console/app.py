"""The operator console: a Textual app that shows a run and sends the operator's commands.

It never runs the engine and never blocks on it: snapshots arrive from a ``Feed`` thread (or, in
replay, from a worker), heatmaps are drawn in worker threads, and commands go out through a single
background thread so they keep their order. Leaving the console never stops the run.
"""

from __future__ import annotations

import getpass
import queue
import threading
import time
from collections.abc import Callable, Iterable
from datetime import datetime
from typing import ClassVar

from textual import work
from textual.app import App, ComposeResult, SystemCommand
from textual.binding import Binding, BindingType
from textual.containers import Horizontal, Vertical
from textual.message import Message
from textual.screen import Screen
from textual.widgets import Footer

from aeni_console.alerts import alert_worthy
from aeni_console.console.feed import Feed, FeedProblem, MapArrived, ReplaySource, RunSource, SnapshotArrived
from aeni_console.console.widgets.adjust import AdjustScreen
from aeni_console.console.widgets.confirm import ConfirmScreen
from aeni_console.console.widgets.cost import CostPanel
from aeni_console.console.widgets.decision import DecisionPanel, shown_scores
from aeni_console.console.widgets.drift import DriftPanel
from aeni_console.console.widgets.help import HelpScreen
from aeni_console.console.widgets.log import LogPanel
from aeni_console.console.widgets.mapview import MapPanel
from aeni_console.console.widgets.queue import QueuePanel
from aeni_console.console.widgets.status import StatusBar
from aeni_console.console.widgets.ticket import AskScreen, TicketPanel
from aeni_console.console.widgets.tray import TrayPanel
from core.errors import InputError
from core.operator import parse_when
from core.run.machine import allowed
from core.runview import Command, CommandKind, EngineState, RunSnapshot

# the command each live key sends: whether it is offered is the state machine's to say
ACTION_COMMANDS: dict[str, CommandKind] = {
    "pause": CommandKind.PAUSE,
    "resume": CommandKind.RESUME,
    "approve": CommandKind.APPROVE,
    "veto": CommandKind.VETO,
    "adjust": CommandKind.ADJUST,
    "step": CommandKind.STEP,
    "stop_after_block": CommandKind.STOP_AFTER_BLOCK,
    "abort": CommandKind.ABORT,
    "away_until": CommandKind.AWAY_UNTIL,
}
LIVE_ACTIONS = frozenset(ACTION_COMMANDS)
# the operator's word on the instrument while a block waits for it (the KLA driver)
INSTRUMENT_ACTIONS = frozenset({"confirm_start", "report_aborted", "report_no_surface", "skip_site"})
REPLAY_ACTIONS = frozenset({"replay_prev", "replay_next", "replay_first", "replay_last"})

# (action, palette title, palette help) — every key is also in the command palette
PALETTE: tuple[tuple[str, str, str], ...] = (
    ("pause", "Pause the run", "Finish the current indent, then wait (space)"),
    ("resume", "Resume the run", "Continue from where it paused (space)"),
    ("approve", "Approve the proposal", "Run the pending block (a)"),
    ("veto", "Veto the proposal", "Avoid that centre; the planner offers the next best (v)"),
    ("adjust", "Adjust the planner", "Target SEM, β, holds, local centres, edge penalty, budgets (e)"),
    ("step", "Step one block", "Switch to step mode and run one block, then wait (s)"),
    ("stop_after_block", "Stop after this block", "Finish the running block, then stop the run (b)"),
    ("abort", "Abort the run", "Stop now, after confirmation (x)"),
    ("away_until", "Away until …", "Nobody answers before this local time: plan for nobody until then (w)"),
    ("confirm_start", "Instrument: array started", "Confirm with the ticket's token (c)"),
    ("report_aborted", "Instrument: array aborted", "The exported rows are kept, the rest not run (a)"),
    ("report_no_surface", "Instrument: surface not found", "The block ends, every site not run (f)"),
    ("skip_site", "Instrument: skip a site", "A site taken out of the array (k)"),
    ("cycle_map", "Cycle the map field", "mean → epistemic sd → noise sd → total sd (m)"),
    ("replay_prev", "Replay: previous block", "One block back (←)"),
    ("replay_next", "Replay: next block", "One block forward (→)"),
    ("replay_first", "Replay: first block", "Jump to the first block (home)"),
    ("replay_last", "Replay: last block", "Jump to the last block (end)"),
    ("help", "Help", "Keys and panels (?)"),
    ("leave", "Leave the console", "The run keeps going (q)"),
)
LEAVE_STOPS = "The demo's engine finishes the indent, lifts and stops (q)"


def describe_payload(payload: dict[str, object]) -> str:
    """A command's payload as the log shows it: the block, or the settings that change."""
    if not payload:
        return ""
    if set(payload) <= {"block_id", "center_um"}:
        return f" (block {payload.get('block_id')})"
    return " " + ", ".join(f"{k}={v}" for k, v in payload.items())


class CommandDone(Message):
    """A command went out (error is None) or was refused (error says why)."""

    def __init__(self, command: Command, error: str | None) -> None:
        super().__init__()
        self.command = command
        self.error = error


class ReplayLoaded(Message):
    """Replay: the snapshot and fields of this block index have been posted."""

    def __init__(self, index: int) -> None:
        super().__init__()
        self.index = index


class ConsoleApp(App[None]):
    """Live console (``source`` is a RunSource) or replay (``replay=True``, source is a ReplaySource)."""

    CSS_PATH = "app.tcss"
    TITLE = "AE-NI console"
    AUTO_FOCUS = None  # no panel takes the keys; every binding is the app's
    # Textual declares the breakpoints as plain class attributes
    HORIZONTAL_BREAKPOINTS = [(0, "-narrow"), (90, "-wide")]  # noqa: RUF012
    VERTICAL_BREAKPOINTS = [(0, "-short"), (28, "-tall")]  # noqa: RUF012
    BINDINGS: ClassVar[list[BindingType]] = [
        # ␣ for space and w before the map: at 80 columns every shown key fits the footer's one line
        Binding("space", "pause", "Pause", key_display="␣"),
        Binding("space", "resume", "Resume", key_display="␣"),
        Binding("a", "approve", "Approve"),
        Binding("c", "confirm_start", "Started"),
        Binding("a", "report_aborted", "Aborted"),
        Binding("f", "report_no_surface", "No surface"),
        Binding("k", "skip_site", "Skip"),
        Binding("v", "veto", "Veto"),
        Binding("e", "adjust", "Adjust"),
        Binding("s", "step", "Step"),
        Binding("b", "stop_after_block", "Stop"),
        Binding("x", "abort", "Abort"),
        Binding("w", "away_until", "Away"),
        Binding("left", "replay_prev", "Prev block"),
        Binding("comma", "replay_prev", "Prev block", show=False),
        Binding("right", "replay_next", "Next block"),
        Binding("full_stop", "replay_next", "Next block", show=False),
        Binding("home", "replay_first", "First", show=False),
        Binding("end", "replay_last", "Last", show=False),
        Binding("m", "cycle_map", "Map"),
        Binding("question_mark", "help", "Help"),
        Binding("q", "leave", "Leave"),
    ]

    def __init__(
        self,
        source: RunSource,
        *,
        replay: bool = False,
        clock: Callable[[], float] = time.time,
        poll_s: float = 0.25,
        max_rate_hz: float = 8.0,
        author: str | None = None,
        cursor_blink: bool = True,
        leaving_stops_engine: bool = False,
    ) -> None:
        super().__init__()
        if replay and not isinstance(source, ReplaySource):
            raise TypeError("replay needs a source with n_blocks() and snapshot_at()")
        self.source = source
        self.replay_mode = replay
        self.clock = clock
        self.poll_s = poll_s
        self.max_rate_hz = max_rate_hz
        self.author = author or getpass.getuser()
        self.cursor_blink = cursor_blink
        # a demo's console owns its engine: leaving stops it, and help and palette must say so
        self.leaving_stops_engine = leaving_stops_engine
        self.snapshot: RunSnapshot | None = None
        self.snapshot_at = 0.0  # self.clock() when the shown snapshot arrived (the wall time runs on from it)
        self.feed: Feed | None = None
        self.replay_index = -1
        self.replay_loaded = -2  # the replay index whose snapshot and fields have been posted
        self.fields_seen: set[int] = set()  # fits whose map fields arrived
        self.replay_count = 0
        self.note = ""
        self.inflight: CommandKind | None = None
        self.sent: list[Command] = []
        self.map_field_changes = 0
        self._commands: queue.Queue[Command | None] = queue.Queue()
        self._sender = threading.Thread(target=self._send_loop, name="aeni-commands", daemon=True)
        self._seen_states: list[EngineState] = []

    # ------------------------------------------------------------------ layout
    def compose(self) -> ComposeResult:
        # kept as attributes: a modal screen on top must not hide the panels from updates
        self.status_bar = StatusBar(id="status")
        self.map_panel = MapPanel(no_color=self.no_color, id="map")
        self.cost_panel = CostPanel(id="cost")
        self.tray_panel = TrayPanel(id="tray")
        self.tray_panel.display = False  # a tray run's samples (shown once a snapshot says it is one)
        self.decision_panel = DecisionPanel(id="decision")
        self.decision_panel.replay = self.replay_mode
        self.ticket_panel = TicketPanel(id="ticket")
        self.ticket_panel.display = False
        self.queue_panel = QueuePanel(id="queue")
        self.drift_panel = DriftPanel(id="drift")
        self.log_panel = LogPanel(id="log")
        yield self.status_bar
        with Horizontal(id="main"):
            with Vertical(id="left"):
                yield self.map_panel
                yield self.tray_panel
                yield self.cost_panel
            with Vertical(id="right"):
                yield self.ticket_panel
                yield self.decision_panel
                yield self.queue_panel
                yield self.drift_panel
                yield self.log_panel
        yield Footer(compact=True, show_command_palette=False)

    def on_mount(self) -> None:
        for widget in (
            self.map_panel,
            self.cost_panel,
            self.tray_panel,
            self.decision_panel,
            self.queue_panel,
            self.drift_panel,
            self.log_panel,
            self.ticket_panel,
        ):
            title = getattr(widget, "BORDER_TITLE", None)
            if title and not widget.border_title:
                widget.border_title = title
        self._show_status()
        self._sender.start()
        if self.replay_mode:
            self._load_replay_count()
        else:
            self.feed = Feed(self.source, self.post_message, poll_s=self.poll_s, max_rate_hz=self.max_rate_hz)
            self.feed.start()
        self.set_interval(1.0, self._show_status)

    def on_unmount(self) -> None:
        if self.feed is not None:
            self.feed.stop()
        self._commands.put(None)
        self._sender.join(timeout=5.0)  # a command already sent must reach the journal before we leave

    # ------------------------------------------------------------------ data in
    def on_snapshot_arrived(self, message: SnapshotArrived) -> None:
        self.apply_snapshot(message.snapshot)

    def on_map_arrived(self, message: MapArrived) -> None:
        self.fields_seen.add(message.fields.snapshot_id)
        self.map_panel.set_fields(message.fields)

    def on_feed_problem(self, message: FeedProblem) -> None:
        self.note = message.text
        self._show_status()

    def apply_snapshot(self, snap: RunSnapshot) -> None:
        if not self.status_bar.is_mounted or not self.screen_stack:
            return  # leaving: the panels are gone
        old = self.snapshot
        self.snapshot = snap
        self.snapshot_at = self.clock()
        self.note = ""
        self.inflight = None
        if (
            old is None
            or old.queue != snap.queue
            or old.pending != snap.pending
            or old.instrument_s != snap.instrument_s
        ):
            self.queue_panel.show(snap)
        if old is None or old.ledger != snap.ledger or old.instrument_s != snap.instrument_s:
            self.cost_panel.show(snap)
        if old is None or old.drift != snap.drift:
            self.drift_panel.show(snap)
        if old is None or old.tray != snap.tray:
            self.tray_panel.show(snap)
        if (
            old is None
            or old.pending != snap.pending
            or old.last_decision != snap.last_decision
            or old.state != snap.state
            or old.gp != snap.gp
            or old.approval_deadline != snap.approval_deadline
        ):
            self.decision_panel.now_unix = self.clock()
            self.decision_panel.show(snap)
        if old is None or old.log != snap.log:
            self.log_panel.show_events(snap.log)
            if old is not None and not self.replay_mode and alert_worthy(set(snap.log) - set(old.log)):
                self.bell()  # what the run's alerts are sent for (aeni_console.alerts)
        waiting = snap.instrument_wait is not None
        self.ticket_panel.display = waiting
        self.decision_panel.display = self.queue_panel.display = self.drift_panel.display = not waiting
        if waiting and (old is None or old.instrument_wait != snap.instrument_wait):
            self.ticket_panel.now_unix = self.clock()
            self.ticket_panel.show(snap)
        self.map_panel.set_snapshot(snap)
        self._show_status()
        if old is None or old.state != snap.state:
            self._seen_states.append(snap.state)
            self._state_changed(old, snap)
        self.refresh_bindings()

    def _state_changed(self, old: RunSnapshot | None, snap: RunSnapshot) -> None:
        if self.replay_mode:
            return
        if snap.state is EngineState.AWAITING_APPROVAL and snap.can_command:
            why = "collapse alarm" if snap.gp.collapse_alarm else "proposal"
            self.notify(
                f"{why.capitalize()} waiting: a approve · v veto · e adjust", title="AWAITING APPROVAL"
            )
            self.bell()
        elif snap.state is EngineState.WAITING_FOR_INSTRUMENT and snap.can_command:
            self.notify(
                "Run the ticket on the instrument; c confirms the start with its token",
                title="WAITING FOR INSTRUMENT",
            )
            self.bell()
        elif snap.finished and (old is None or not old.finished):
            self.notify(f"The run has ended ({snap.state.label}).", title="Run ended")
            self.bell()

    def _show_status(self) -> None:
        if not self.status_bar.is_mounted:
            return
        replay = (self.replay_index, self.replay_count) if self.replay_mode and self.replay_count else None
        now = self.clock()
        snap = self.snapshot
        wall_s = None
        if snap is not None and not snap.finished and not self.replay_mode:
            # a snapshot is read only when the journal changes: the session's wall time runs on meanwhile
            wall_s = snap.wall_s + max(now - self.snapshot_at, 0.0)
        self.status_bar.show(snap, now, replay, self.note, wall_s)
        if self.ticket_panel.display:
            self.ticket_panel.tick(self.clock())
        elif self.decision_panel.display:
            self.decision_panel.tick(self.clock())

    # ------------------------------------------------------------------ which keys apply now
    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        if action in REPLAY_ACTIONS:
            if not self.replay_mode:
                return False
            if action in ("replay_prev", "replay_first"):
                return self.replay_index > 0
            return 0 <= self.replay_index < self.replay_count - 1
        if action not in LIVE_ACTIONS | INSTRUMENT_ACTIONS:
            return True
        snap = self.snapshot
        if self.replay_mode or snap is None or not snap.can_command or snap.finished:
            return False
        st = snap.state
        if action in INSTRUMENT_ACTIONS:
            return allowed(st, CommandKind.CONFIRM) and snap.instrument_wait is not None
        if self.inflight is not None and action in ("approve", "veto", "step"):
            return False
        if action == "step":  # switch to step mode, or release what waits: nothing while a step block runs
            if st is EngineState.RUNNING:
                return snap.supervision != "step"
            return allowed(st, CommandKind.STEP) or allowed(st, CommandKind.RESUME)
        if action in ("approve", "veto") and snap.pending is None:
            return False
        return allowed(st, ACTION_COMMANDS[action])  # the state machine's table (core.run.machine)

    def get_system_commands(self, screen: Screen) -> Iterable[SystemCommand]:
        for action, title, help_ in PALETTE:
            if action == "leave" and self.leaving_stops_engine:
                help_ = LEAVE_STOPS
            if self.check_action(action, ()):
                yield SystemCommand(title, help_, lambda a=action: self.run_action(a))
        yield from super().get_system_commands(screen)

    # ------------------------------------------------------------------ commands out
    def send_command(
        self,
        kind: CommandKind,
        payload: dict[str, object] | None = None,
        scores: dict[str, float] | None = None,
    ) -> Command:
        cmd = Command(
            kind=kind, author=self.author, payload=dict(payload or {}), shown_scores=dict(scores or {})
        )
        self.inflight = kind
        self.sent.append(cmd)
        self._commands.put(cmd)
        self.log_panel.note(f"sent {kind.value}{describe_payload(cmd.payload)}")
        self.refresh_bindings()
        return cmd

    def _send_loop(self) -> None:
        """The one thread that writes commands, in the order the operator gave them."""
        while True:
            cmd = self._commands.get()
            if cmd is None:
                return
            error: str | None = None
            try:
                self.source.send(cmd)
            except Exception as exc:  # the operator must see why, the console must live on
                error = str(exc) or type(exc).__name__
            self.post_message(CommandDone(cmd, error))
            if self.feed is not None:
                self.feed.poke()

    def on_command_done(self, message: CommandDone) -> None:
        if message.error is not None:
            self.inflight = None
            self.log_panel.note(f"{message.command.kind.value} refused: {message.error}", "error")
            self.notify(message.error, title=f"{message.command.kind.value} refused", severity="error")
            self.refresh_bindings()

    def _pending_scores(self) -> dict[str, float]:
        snap = self.snapshot
        return shown_scores(snap.pending) if snap is not None and snap.pending is not None else {}

    def action_pause(self) -> None:
        self.send_command(CommandKind.PAUSE)

    def action_resume(self) -> None:
        self.send_command(CommandKind.RESUME)

    def action_approve(self) -> None:
        snap = self.snapshot
        assert snap is not None and snap.pending is not None
        b = snap.pending.block
        self.send_command(
            CommandKind.APPROVE,
            {"block_id": b.block_id, "center_um": [b.center_x_um, b.center_y_um]},
            self._pending_scores(),
        )

    def action_veto(self) -> None:
        snap = self.snapshot
        assert snap is not None and snap.pending is not None
        b = snap.pending.block
        self.send_command(
            CommandKind.VETO,
            {"block_id": b.block_id, "center_um": [b.center_x_um, b.center_y_um]},
            self._pending_scores(),
        )

    def action_step(self) -> None:
        """Run one block, then wait: switch to step supervision, and release the waiting or paused block."""
        snap = self.snapshot
        assert snap is not None
        if snap.supervision != "step":
            self.send_command(CommandKind.ADJUST, {"supervision": "step"})
        if snap.state is EngineState.AWAITING_APPROVAL and snap.pending is not None:
            b = snap.pending.block
            self.send_command(CommandKind.STEP, {"block_id": b.block_id}, self._pending_scores())
        elif snap.state is EngineState.PAUSED:
            self.send_command(CommandKind.RESUME)

    def action_stop_after_block(self) -> None:
        self.send_command(CommandKind.STOP_AFTER_BLOCK)

    def action_adjust(self) -> None:
        snap = self.snapshot
        assert snap is not None

        def done(changes: dict[str, object] | None) -> None:
            if changes:
                self.send_command(CommandKind.ADJUST, changes)
            elif changes is not None:
                self.notify("Nothing changed.", title="Adjust")

        self.push_screen(
            AdjustScreen(
                snap.settings,
                snap.supervision,
                cursor_blink=self.cursor_blink,
                allowed_holds_s=snap.allowed_holds_s or None,
                policy=snap.policy,
            ),
            done,
        )

    def action_abort(self) -> None:
        def done(yes: bool | None) -> None:
            if yes:
                self.send_command(CommandKind.ABORT)

        name = self.snapshot.run_name if self.snapshot is not None else "the run"
        self.push_screen(
            ConfirmScreen(
                f"Abort {name} now? The instrument stops after the current step; this cannot be undone."
            ),
            done,
        )

    def _ask_instrument(self, question: str, placeholder: str, send: Callable[[str], object]) -> None:
        def done(answer: str | None) -> None:
            if answer:
                send(answer)

        self.push_screen(AskScreen(question, placeholder, cursor_blink=self.cursor_blink), done)

    def _block_now(self) -> int:
        snap = self.snapshot
        assert snap is not None and snap.instrument_wait is not None
        return snap.instrument_wait.block_id

    def action_confirm_start(self) -> None:
        self._ask_instrument(
            f"Block {self._block_now()}: the array has started. Type the token from the ticket:",
            "token",
            lambda token: self.send_command(CommandKind.CONFIRM, {"token": token}),
        )

    def action_report_aborted(self) -> None:
        self._ask_instrument(
            f"Block {self._block_now()} was aborted: the exported rows are kept, the rest not run. Token:",
            "token",
            lambda token: self.send_command(CommandKind.REPORT, {"kind": "aborted", "token": token}),
        )

    def action_report_no_surface(self) -> None:
        self._ask_instrument(
            f"Block {self._block_now()}: InView found no surface; every site becomes not run. Token:",
            "token",
            lambda token: self.send_command(
                CommandKind.REPORT, {"kind": "surface-not-found", "token": token}
            ),
        )

    def action_skip_site(self) -> None:
        self._ask_instrument(
            f"Block {self._block_now()}: which site did you take out of the array (1-based, as in the sites file)?",
            "site number",
            lambda site: self.send_command(CommandKind.SKIP, {"site": site}),
        )

    def action_away_until(self) -> None:

        def send(text: str) -> None:
            try:
                until = parse_when(text, datetime.now(), "away-until")
            except InputError as exc:
                self.log_panel.note(str(exc))
                return
            self.send_command(CommandKind.AWAY_UNTIL, {"until": until.isoformat(timespec="minutes")})

        self._ask_instrument(
            "Away until when (local time)? Until then the run plans for nobody.", "08:00", send
        )

    def action_cycle_map(self) -> None:
        self.map_field_changes += 1
        self.map_panel.cycle()

    def action_help(self) -> None:
        self.push_screen(HelpScreen(self.leaving_stops_engine))

    def action_leave(self) -> None:
        self.exit()

    # ------------------------------------------------------------------ replay
    @work(thread=True, exclusive=True, group="replay")
    def _load_replay_count(self) -> None:
        assert isinstance(self.source, ReplaySource)
        n = self.source.n_blocks()
        self.call_from_thread(self._replay_ready, n)

    def _replay_ready(self, n: int) -> None:
        self.replay_count = n
        if n == 0:
            self.note = "this run has no finished block to replay"
            self._show_status()
            return
        self.replay_goto(n - 1)

    def replay_goto(self, index: int) -> None:
        if not self.replay_count:
            return
        index = max(0, min(index, self.replay_count - 1))
        self.replay_index = index
        self._show_status()
        self.refresh_bindings()
        self._load_replay(index)

    @work(thread=True, exclusive=True, group="replay")
    def _load_replay(self, index: int) -> None:
        assert isinstance(self.source, ReplaySource)
        snap = self.source.snapshot_at(index)
        fields = self.source.map_fields(snap.gp.snapshot_id) if snap.gp.snapshot_id is not None else None
        if index != self.replay_index:
            return  # the operator already moved on
        self.post_message(SnapshotArrived(snap))
        if fields is not None:
            self.post_message(MapArrived(fields))
        self.post_message(ReplayLoaded(index))  # after the two above, in queue order

    def on_replay_loaded(self, message: ReplayLoaded) -> None:
        self.replay_loaded = message.index

    def action_replay_prev(self) -> None:
        self.replay_goto(self.replay_index - 1)

    def action_replay_next(self) -> None:
        self.replay_goto(self.replay_index + 1)

    def action_replay_first(self) -> None:
        self.replay_goto(0)

    def action_replay_last(self) -> None:
        self.replay_goto(self.replay_count - 1)

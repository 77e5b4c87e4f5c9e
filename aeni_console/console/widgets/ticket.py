"""The ticket panel (WAITING FOR INSTRUMENT): what to load, where to move, which method, the deadline.

It replaces the decision and queue panels while a block waits for the instrument, and counts the deadline
down every second. The token is not shown: the operator reads it on the ticket at the instrument PC and
types it here (c), which proves the right ticket is being run.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import ClassVar

from rich.console import Group
from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Input, Static

from aeni_console.console.widgets.base import SnapshotPanel
from aeni_console.console.widgets.fmt import hms
from core.describe import block_words
from core.driver import InstrumentWait
from core.plan import Block
from core.runview import RunSnapshot


def seconds_left(wait: InstrumentWait, now_unix: float) -> float:
    deadline = datetime.fromisoformat(wait.deadline_utc)
    return (deadline - datetime.fromtimestamp(now_unix, UTC)).total_seconds()


def ticket_renderable(wait: InstrumentWait, now_unix: float, block: Block | None = None) -> Group:
    """The ticket as the driver wrote it; ``block``: the block it runs, named first when it is a fast array
    (an operator must not load it as a CSM method)."""
    left = seconds_left(wait, now_unix)
    head = Text(no_wrap=True, overflow="ellipsis")
    head.append(f" block {wait.block_id} ", style="bold black on cyan")
    head.append(" deadline in ")
    head.append(hms(left) if left > 0 else "PASSED", style="bold" if left > 300 else "bold red")
    start = Text(no_wrap=True, overflow="ellipsis")
    if wait.started:
        start.append("✓ start confirmed", style="bold green")
    else:
        start.append("start not confirmed: ", style="bold yellow")
        start.append("c + token")
    body = Text("\n".join(wait.panel or wait.ticket.splitlines()), no_wrap=True, overflow="ellipsis")
    inbox = Text(no_wrap=True, overflow="ellipsis")
    inbox.append("inbox: ", style="dim")
    inbox.append(wait.waiting)
    keys = Text(
        "c start · a aborted · f no surface · k skip", style="italic", no_wrap=True, overflow="ellipsis"
    )
    lines = [head, start, body, inbox, keys]
    if block is not None and block.block_id == wait.block_id and block.channel == "fast":
        words = block_words(block)
        fast = Text(no_wrap=True, overflow="ellipsis")
        fast.append(" FAST ARRAY ", style="bold black on bright_cyan")
        fast.append(f" {block.n_indents} indents, {words.layout.removeprefix('fast array ')} {words.extent}")
        lines.insert(1, fast)
    return Group(*lines)


class TicketPanel(SnapshotPanel):
    BORDER_TITLE = "Ticket: WAITING FOR INSTRUMENT"

    now_unix: float = 0.0

    def show(self, snap: RunSnapshot) -> None:
        self.snap = snap
        if snap.instrument_wait is not None:
            self.update(ticket_renderable(snap.instrument_wait, self.now_unix, snap.current_block))

    def tick(self, now_unix: float) -> None:
        """The countdown: redraw with the current time."""
        self.now_unix = now_unix
        if self.snap is not None and self.snap.instrument_wait is not None:
            self.update(ticket_renderable(self.snap.instrument_wait, now_unix, self.snap.current_block))


class AskScreen(ModalScreen[str | None]):
    """One line of input (a token, a site number); escape cancels."""

    BINDINGS: ClassVar[list[BindingType]] = [Binding("escape", "cancel", "Cancel")]

    def __init__(self, question: str, placeholder: str, *, cursor_blink: bool = True) -> None:
        super().__init__()
        self.question = question
        self.placeholder = placeholder
        self.cursor_blink = cursor_blink

    def compose(self) -> ComposeResult:
        with Vertical(id="ask-dialog"):
            yield Static(self.question, id="ask-question")
            yield Input(placeholder=self.placeholder, id="ask-input")
            yield Static("enter sends · escape cancels", id="ask-help")

    def on_mount(self) -> None:
        field = self.query_one("#ask-input", Input)
        field.cursor_blink = self.cursor_blink
        field.focus()

    def on_input_submitted(self, event: Input.Submitted) -> None:
        self.dismiss(event.value.strip() or None)

    def action_cancel(self) -> None:
        self.dismiss(None)

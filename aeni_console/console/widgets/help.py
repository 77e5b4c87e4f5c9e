"""The help screen: every key, what each panel shows, and how leaving works."""

from __future__ import annotations

from typing import ClassVar

from rich.table import Table
from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Static

KEYS: tuple[tuple[str, str], ...] = (
    ("space", "pause / resume the run (a running block finishes its current indent first)"),
    ("a", "approve the pending proposal"),
    ("v", "veto it: the planner offers the next best and avoids that centre for a while"),
    ("e", "adjust target SEM, β, holds, local centres, edge penalty, budgets"),
    ("s", "step: switch to step mode, run one block, then wait again"),
    ("b", "stop after the current block"),
    ("x", "abort now (asks first)"),
    ("w", "away until a time (08:00, 'Mon 09:00'): the run plans for nobody until then, then for you again"),
    (
        "m",
        "cycle the map: mean → epistemic sd → noise sd → total sd, then the modulus, H/E and the fast "
        "channel's bias where the run has them",
    ),
    ("← →  , .", "replay: one block back / forward (home / end: first / last)"),
    ("ctrl+p", "command palette (every action, searchable)"),
    ("?", "this help"),
    ("q", "leave the console: the run keeps going"),
)

# the ticket keys: they act only in WAITING FOR INSTRUMENT (a KLA run), where "a" reports instead of approving
INSTRUMENT_KEYS: tuple[tuple[str, str], ...] = (
    ("c", "the array has started: type the ticket's token (journaled)"),
    ("a", "report the array aborted (token): exported rows kept, the rest not run"),
    ("f", "report surface not found (token): every site not run"),
    ("k", "skip a site: its number in the sites file (1-based)"),
)

PANELS: tuple[tuple[str, str], ...] = (
    (
        "Map",
        "GP fields on the sample as the microscope shows it; ◉ newest, ● recent, • older centres, + next",
    ),
    ("Decision", "what the planner proposes, its scores, predicted cost and next-best alternatives"),
    ("Queue", "indents still to run, with grid size, hold and ETA on the instrument clock"),
    ("Cost", "instrument seconds by category against the 9×9-of-5×5 grid baseline"),
    ("Drift", "last drift rate, hold mode, area error against the 2 % threshold, drift events"),
    ("Log", "decisions, commands (with their author) and warnings"),
    ("Ticket", "WAITING FOR INSTRUMENT: what to load, where to move, which method, the deadline"),
)


LEAVE_STOPS = "leave the console: the demo's engine finishes the indent, lifts and stops"


def help_text(leaving_stops_engine: bool = False) -> Table:
    table = Table.grid(padding=(0, 2))
    table.add_column(style="bold cyan", no_wrap=True)
    table.add_column()
    table.add_row(Text("Keys", style="bold underline"), "")
    for key, what in KEYS:
        table.add_row(key, LEAVE_STOPS if key == "q" and leaving_stops_engine else what)
    table.add_row("", "")
    # a short heading: the key column stays as wide as the keys
    table.add_row(
        Text("Ticket", style="bold underline"), Text("in WAITING FOR INSTRUMENT (a KLA run)", style="dim")
    )
    for key, what in INSTRUMENT_KEYS:
        table.add_row(key, what)
    table.add_row("", "")
    table.add_row(Text("Panels", style="bold underline"), "")
    for name, what in PANELS:
        table.add_row(name, what)
    table.add_row("", "")
    table.add_row("", Text("Keys appear in the footer only when they apply to the run's state.", style="dim"))
    return table


class HelpScreen(ModalScreen[None]):
    BINDINGS: ClassVar[list[BindingType]] = [Binding("escape,q,question_mark", "close", "Close")]

    def __init__(self, leaving_stops_engine: bool = False) -> None:
        super().__init__()
        self.leaving_stops_engine = leaving_stops_engine

    def compose(self) -> ComposeResult:
        with VerticalScroll(id="help-dialog"):
            yield Static(help_text(self.leaving_stops_engine))

    def on_mount(self) -> None:
        self.query_one("#help-dialog").border_title = "Help"
        self.query_one("#help-dialog").border_subtitle = "esc to close"

    def action_close(self) -> None:
        self.dismiss(None)

"""Decision panel: the proposal waiting for the operator (or the last one), and why the planner chose it."""

from __future__ import annotations

import math
import time

from rich.console import Group
from rich.table import Table
from rich.text import Text

from aeni_console.console.widgets.base import SnapshotPanel
from aeni_console.console.widgets.fmt import bar, num, short_duration, xy
from core.describe import block_words
from core.plan import Decision
from core.runview import EngineState, RunSnapshot


def shown_scores(decision: Decision) -> dict[str, float]:
    """The numbers the operator saw, recorded with an approve or veto."""
    out = {
        "score": float(decision.score),
        "acquisition": float(decision.acquisition),
        "predicted_cost_s": float(decision.predicted_cost_s),
    }
    if decision.stay_score is not None:
        out["stay_score"] = float(decision.stay_score)
    if decision.jump_score is not None:
        out["jump_score"] = float(decision.jump_score)
    return out


def countdown(seconds: float) -> str:
    """0:42, 12:05, 1:02:03: the time left to answer."""
    total = max(math.ceil(seconds), 0)
    h, rest = divmod(total, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


def deadline_text(snap: RunSnapshot, now_unix: float) -> Text | None:
    """How long the waiting decision has before the engine answers it itself, and how."""
    dl = snap.approval_deadline
    if dl is None or snap.state is not EngineState.AWAITING_APPROVAL:
        return None
    t = Text(no_wrap=True, overflow="ellipsis")
    t.append(f"⏱ answer in {countdown(dl.remaining_s(now_unix))}", style="bold yellow")
    t.append(f" → {dl.on_timeout}", style="bold")
    t.append(" (approval_timeout_s)", style="dim")
    return t


def decision_renderable(
    snap: RunSnapshot, width: int, replay: bool = False, now_unix: float | None = None
) -> Group | Text:
    waiting = snap.state is EngineState.AWAITING_APPROVAL and snap.pending is not None
    d = snap.pending if snap.pending is not None else snap.last_decision
    parts: list[object] = []
    if snap.gp.collapse_alarm:
        alarm = Text()
        alarm.append("⚠ length-scale collapse", style="bold red")
        alarm.append(f": {snap.gp.collapse_reason or 'a length-scale fell below its floor'}\n")
        alarm.append("approve keeps the last good hyper-parameters; e adjusts; x aborts", style="italic")
        parts.append(alarm)
    if d is None:
        parts.append(Text("no decision yet: the planner is waiting for data", style="dim"))
        return Group(*parts)  # type: ignore[arg-type]
    b = d.block
    # the pending block starts where the tip is now; a past one's start is not known here
    start = snap.position_um if d is snap.pending else None
    words = block_words(b, snap.reconfig_threshold_um, start)
    head = Text(no_wrap=True, overflow="ellipsis")
    if replay and snap.pending is not None:
        head.append(" NEXT ", style="bold black on cyan")
    elif waiting:
        head.append(" PROPOSAL ", style="bold white on magenta")
    else:
        head.append(" pending " if snap.pending is not None else " last ", style="reverse")
    head.append(" ")
    program_style = (
        "bold yellow"
        if words.program == "new program"
        else "bold green"
        if words.program == "stay"
        else "bold"
    )
    head.append(words.program.upper(), style=program_style)
    head.append(f" {words.layout}")
    parts.append(head)
    due = None if replay else deadline_text(snap, time.time() if now_unix is None else now_unix)
    if due is not None:
        parts.append(due)
    where = Text(no_wrap=True, overflow="ellipsis")
    # where first: at 80 columns the line is cut, and the coordinates are what the operator checks
    where.append(f"#{b.block_id} " + " ".join(p for p in (words.where, words.extent) if p))
    parts.append(where)
    sc = Text(no_wrap=True, overflow="ellipsis")
    sc.append(f"{words.hold} · ")
    sc.append(f"≈{short_duration(d.predicted_cost_s)}", style="bold")
    sc.append(f" · score {num(d.score)}", style="bold")
    sc.append(f" · acq {num(d.acquisition)} · {d.policy}")
    if d.phase:
        sc.append(f" · {d.phase}", style="dim")
    parts.append(sc)
    if d.stay_score is not None or d.jump_score is not None:
        top = max(v for v in (d.stay_score, d.jump_score, 1e-12) if v is not None)
        w = max(min((width - 28) // 2, 14), 3)
        t = Text(no_wrap=True, overflow="ellipsis")
        for name, val, style in (("stay", d.stay_score, "green"), ("jump", d.jump_score, "yellow")):
            t.append(f"{name} ", style="bold")
            if val is None:
                t.append("–" + " " * (w + 8))
            else:
                t.append(bar(val / top, w), style=style)
                t.append(f" {num(val):<7}")
            t.append(" ")
        parts.append(t)
    if d.reason:
        parts.append(Text(d.reason, style="italic", no_wrap=True, overflow="ellipsis"))
    if d.alternatives:
        alts = d.alternatives[:3]
        places = [xy(a.center_x_um, a.center_y_um) for a in alts]
        # whole coordinates on one line, always: the score column goes first when the panel is narrow
        # (the alternatives come in score order, and the proposal's own score is shown above)
        with_score = width >= max(len(p) for p in places) + 6 + 7 + 8 + 3
        table = Table(
            box=None,
            padding=(0, 1),
            collapse_padding=True,
            pad_edge=False,
            show_edge=False,
            expand=False,
            header_style="bold dim",
        )
        table.add_column("next best", no_wrap=True)
        table.add_column("kind", no_wrap=True, overflow="ellipsis")
        if with_score:
            table.add_column("score", justify="right", no_wrap=True)
        table.add_column("cost", justify="right", no_wrap=True)
        for alt, place in zip(alts, places, strict=True):
            row = [place, alt.kind, num(alt.score)] if with_score else [place, alt.kind]
            table.add_row(*row, short_duration(alt.cost_s))
        parts.append(table)
    return Group(*parts)  # type: ignore[arg-type]


class DecisionPanel(SnapshotPanel):
    """The pending proposal, stay-vs-jump scores, predicted cost and the next-best alternatives."""

    BORDER_TITLE = "Decision"

    replay = False  # in replay the pending decision is the one the planner made after this block

    now_unix: float = 0.0  # the console's clock, for the approval countdown

    def tick(self, now_unix: float) -> None:
        """The approval countdown goes on between snapshots (the console calls this every second)."""
        self.now_unix = now_unix
        if self.snap is not None and self.snap.approval_deadline is not None and not self.replay:
            self.show(self.snap)

    def show(self, snap: RunSnapshot) -> None:
        self.snap = snap
        self.update(decision_renderable(snap, max(self.size.width - 2, 20), self.replay, self.now_unix))
        waiting = snap.state is EngineState.AWAITING_APPROVAL and not self.replay
        self.set_class(waiting, "-waiting")
        self.set_class(snap.gp.collapse_alarm, "-alarm")
        if waiting and snap.can_command:
            self.border_subtitle = "a approve · v veto · e adjust"
        elif waiting:
            self.border_subtitle = "awaiting the owner"
        elif self.replay:
            self.border_subtitle = "replay: ← → move a block"
        else:
            self.border_subtitle = ""

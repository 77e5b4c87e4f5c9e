"""A block in words: what the decision panel, the log and the instrument ticket call it.

One function so they cannot disagree. A block of scattered singles is named by its sites, their extent and
the program it runs in, never by its centre alone (its sites may lie a millimetre from it); "stay" is said
only when the block continues the engaged program with no reconfiguration on the way.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from itertools import pairwise

from core.plan import Block


@dataclass(frozen=True)
class BlockWords:
    """The parts of a block's description, for a caller that lays them out itself (the console's panel)."""

    program: str  # "new program" | "stay" | "same program" | "same program, N reconfigurations"
    layout: str  # "3×3 grid at 5 µm pitch" | "16 singles" | "1 single"
    extent: str  # "over 1196 × 840 µm" ("" for one site)
    where: str  # "around (x, y) µm": the middle of the sites' extent
    hold: str  # "hold 5 s"

    @property
    def text(self) -> str:
        body = " ".join(p for p in (self.layout, self.extent, self.where) if p)
        return f"{self.program}: {body}" + (f", {self.hold}" if self.hold else "")


def hops_needing_reconfiguration(
    kind: str,
    sites_um: Sequence[tuple[float, float]],
    reconfig_threshold_um: float,
    start_um: tuple[float, float] | None = None,
) -> int:
    """Engaged moves between the sites that the safety rule turns into a lift and re-engage (as core.cost
    prices them: a global block's first move is made lifted; a local block starts engaged at ``start_um``)."""
    pts = list(sites_um)
    if kind == "local" and start_um is not None:
        pts.insert(0, start_um)
    t = reconfig_threshold_um
    return sum(1 for (x0, y0), (x1, y1) in pairwise(pts) if abs(x1 - x0) >= t or abs(y1 - y0) >= t)


def sites_words(
    kind: str,
    sites_um: Sequence[tuple[float, float]],
    grid_g: int,
    pitch_um: float,
    hold_s: float | None,
    reconfig_threshold_um: float | None = None,
    start_um: tuple[float, float] | None = None,
) -> BlockWords:
    """Describe an array of sites (a block, or what is left of one on a ticket). Without
    ``reconfig_threshold_um`` a local array is "same program" (whether it reconfigures is not known),
    never "stay"."""
    n = len(sites_um)
    if kind == "global":
        program = "new program"
    elif reconfig_threshold_um is None:
        program = "same program"
    else:
        k = hops_needing_reconfiguration(kind, sites_um, reconfig_threshold_um, start_um)
        program = "stay" if k == 0 else f"same program, {k} reconfiguration{'s' if k > 1 else ''}"
    if grid_g > 1 and n == grid_g**2:
        layout = f"{grid_g}×{grid_g} grid at {pitch_um:g} µm pitch"
    else:
        layout = f"{n} single{'s' if n != 1 else ''}"
    if n == 0:
        return BlockWords(program, layout, "", "", "" if hold_s is None else f"hold {hold_s:g} s")
    xs = [x for x, _ in sites_um]
    ys = [y for _, y in sites_um]
    dx, dy = max(xs) - min(xs), max(ys) - min(ys)
    extent = f"over {dx:.0f} × {dy:.0f} µm" if n > 1 else ""
    mx, my = (max(xs) + min(xs)) / 2, (max(ys) + min(ys)) / 2
    where = f"around ({mx:.0f}, {my:.0f}) µm" if n > 1 else f"at ({mx:.0f}, {my:.0f}) µm"
    return BlockWords(program, layout, extent, where, "" if hold_s is None else f"hold {hold_s:g} s")


def block_words(
    block: Block,
    reconfig_threshold_um: float | None = None,
    start_um: tuple[float, float] | None = None,
) -> BlockWords:
    """Describe ``block`` (see :func:`sites_words`; a fast array: :func:`fast_array_words`)."""
    sites = [(s.x_um, s.y_um) for s in block.indents]
    if block.channel == "fast":
        return fast_array_words(sites, block.pitch_um)
    return sites_words(
        block.kind, sites, block.grid_g, block.pitch_um, block.hold_s, reconfig_threshold_um, start_um
    )


def describe_block(
    block: Block,
    reconfig_threshold_um: float | None = None,
    start_um: tuple[float, float] | None = None,
) -> str:
    """One line, e.g. "new program: 16 singles over 1196 × 840 µm around (2400, 1800) µm, hold 5 s"."""
    return block_words(block, reconfig_threshold_um, start_um).text


def fast_array_words(sites_um: Sequence[tuple[float, float]], pitch_um: float) -> BlockWords:
    """A fast (NanoBlitz-class) array: its own program of load-controlled indents, named as one, e.g. "new
    program: fast array 20×20 at 50 µm pitch over 950 × 950 µm around (500, 500) µm, 400 indents, no hold";
    columns and rows are the distinct x and y of its sites (sites a sample does not allow are left out, so an
    array may hold fewer than columns × rows)."""
    words = sites_words("global", sites_um, 1, pitch_um, None)
    n = len(sites_um)
    cols = len({round(x, 3) for x, _ in sites_um})
    rows = len({round(y, 3) for _, y in sites_um})
    layout = f"fast array {cols}×{rows} at {pitch_um:g} µm pitch"
    return replace(words, layout=layout, hold=f"{n} indent{'s' if n != 1 else ''}, no hold")

"""The policies a user chooses from, by name, with their one-line descriptions.

A table with no planner behind it: the CLI offers these names (``--policy`` choices) without importing the
model and torch (the startup time of ``aeni --help``). :mod:`core.policies.registry` builds each policy.
"""

from __future__ import annotations

RECOMMENDED = "aeni"

POLICY_DESCRIPTIONS: dict[str, str] = {
    "aeni": "recommended: space-filling start, then scattered single indents placed where the map is least "
    "known (weighted to its structure), blocks ordered for travel, Student-t noise, drift-aware hold; reads "
    "the run: stretches to the operator's next visit with a calendar, programs priced over their life where "
    "the profile's program change is dear",
    "grid": "fixed 9×9 blocks of 5×5 (the paper's baseline)",
    "uncertainty": "jump to the highest-σ centre after every block, fixed 5×5, cost ignored",
    "cost-aware": "σ/cost with staying engaged priced against a global jump, fixed 5×5",
    "adaptive-grid": "σ/cost, a new program every block, grid size 2×2…5×5 from the noise and the target SEM",
    "meta-grid": "adaptive grid + sub-grids ≤ 500 µm apart in the safe band, stay-vs-jump after each",
    "adaptive-hold": "cost-aware with a drift-aware 5 s / 80 s hold and the g²·(80 − 5) switch rule",
    "aeni-paper": "the paper's real-film workflow: seeds, exploratory phase, meta-grid, adaptive grid and hold",
}


def policy_names() -> tuple[str, ...]:
    """The policies a user chooses from: the recommended one first, then the paper's references."""
    return tuple(POLICY_DESCRIPTIONS)

"""``aeni simulate``: one headless emulator campaign, start to finish."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from aeni_console.cli.common import (
    add_operator_args,
    dumps,
    ledger_table,
    map_weights_arg,
    operator_calendar,
    positive_float,
    seed_arg,
)
from core.policies.names import RECOMMENDED, policy_names

if TYPE_CHECKING:
    from core.campaign import Campaign
    from core.run.events import RunEvent, Sink
    from core.visits import OperatorCalendar

NOISE_CHOICES = ("hetero", "homo", "10pct")


def _progress(done_s: float, budget_s: float, blocks: int, mape: float | None, start: float) -> None:
    frac = min(done_s / budget_s, 1.0) if budget_s else 0.0
    width = 30
    bar = "#" * int(frac * width) + "-" * (width - int(frac * width))
    m = f"{mape:5.2f} %" if mape is not None else "  —   "
    sys.stderr.write(
        f"\r[{bar}] {100 * frac:5.1f}%  t={done_s / 3600:6.1f} h  blocks={blocks:4d}  MAPE={m}  wall={time.monotonic() - start:5.1f} s"
    )
    sys.stderr.flush()


def run_simulation(
    policy: str,
    seed: int,
    scenario: str = "ternary",
    truth: str | None = None,
    noise: str | None = None,
    drift: str | None = None,
    budget_s: float | None = None,
    lattice_n: int | None = None,
    profile: str | None = None,
    progress: bool = False,
    sample_file: str | None = None,
    failure_rate: float | None = None,
    sinks: Sequence[Sink] = (),
    map_weights: dict[str, float] | None = None,
    calendar: OperatorCalendar | None = None,
    fast: bool = False,
) -> dict[str, Any]:
    """One campaign; the dict has the CLI's JSON keys (a contract).

    The simulated instrument lays the scenario's truth onto the sample (its built-in one by default) and
    its evaluator scores the map; the campaign sees only the sample. ``sinks`` see the run's events.
    With a ``calendar`` a simulated operator loads the blocks, and the run reports its wall clock and visits.
    ``fast``: the plan prices the profile's fast arrays beside its CSM blocks (the policy's ``+fast``).
    """
    # imported here, not at the top: the campaign pulls torch; `aeni --help` must start fast
    from core.run.events import Observed
    from core.run.headless import RunTally, run_headless
    from core.run.spec import RunSpec
    from core.runconfig import make_campaign_config
    from core.sample import load_sample
    from core.settings import settings_to_dict
    from drivers.registry import DRIVERS
    from drivers.sim.emulator import field_extrema
    from drivers.sim.evaluator import TruthEvaluator

    config = make_campaign_config(
        scenario="csv" if truth else scenario,
        noise=noise,
        drift=drift,
        truth_csv=truth,
        policy=policy,
        seed=seed,
        profile=profile,
        lattice_n=lattice_n,
        settings={"budget_s": budget_s, "map_weights": map_weights},
        failure_rate=failure_rate,
        fast="on" if fast else None,
    )
    if sample_file is not None:
        config = dataclasses.replace(config, sample=load_sample(sample_file))
    start = time.monotonic()
    parts: list[tuple[Campaign, TruthEvaluator]] = []  # the run's campaign and scorer, once composed
    modulus: list[tuple[float, float]] = []

    class Progress(RunTally):
        """A second tally of the same events, printing a progress line after every block."""

        def __init__(self, budget_s: float) -> None:
            super().__init__()
            self.budget_s = budget_s

        def emit(self, event: RunEvent) -> None:
            super().emit(event)
            if isinstance(event, Observed):
                mape = self.trajectory[-1][1] if self.trajectory else None
                _progress(event.t_s, self.budget_s, self.blocks, mape, start)

    class ModulusScore(RunTally):
        """The modulus map's MAPE after every refit, for every policy (a run that does not aim at the modulus,
        the grid among them, has its modulus map fitted from the same indents to be scored)."""

        def emit(self, event: RunEvent) -> None:
            if isinstance(event, Observed) and event.fit.fitted:
                campaign, evaluator = parts[0]
                mape = evaluator.score_modulus(campaign)
                if mape is not None:
                    modulus.append((event.t_s, mape))

    def watchers(campaign: Campaign, evaluator: Any) -> list[Sink]:
        assert isinstance(evaluator, TruthEvaluator)  # the simulated instrument's
        parts.append((campaign, evaluator))
        budget = campaign.settings.budget_s or campaign.grid_baseline_s
        return [
            *sinks,
            ModulusScore(),  # every policy, the grid included (issue 37)
            *([Progress(budget)] if progress else []),
        ]

    result, run = run_headless(RunSpec(campaign=config, calendar=calendar), DRIVERS, sinks=watchers)
    campaign, evaluator = parts[0]
    operator = run.visits
    if progress:
        sys.stderr.write("\n")
    score = evaluator.score(campaign)
    modulus_at = dict(modulus)  # both maps read the same way: each point carries the modulus MAPE too
    trajectory: list[dict[str, Any]] = [
        {"t_s": t, "mape_pct": m, "mape_modulus_pct": modulus_at.get(t)} for t, m in result.trajectory
    ]
    calendar_keys: dict[str, Any] = {}
    if operator is not None:
        for point in trajectory:
            wall = operator.wall_at(point["t_s"])
            point["wall_clock_h"] = None if wall is None else wall / 3600.0
            point["operator_visits"] = operator.visits_at(point["t_s"])
        calendar_keys = {
            "start": calendar.start.isoformat(timespec="minutes") if calendar is not None else None,
            "wall_clock_h": operator.wall_s(result.instrument_s) / 3600.0,
            "operator_visits": operator.visits,
        }
    return {
        "policy": config.policy,
        "scenario": config.driver_options["scenario"],
        "sample": campaign.sample.name,
        "seed": seed,
        "profile": campaign.profile.name,
        "instrument_s": result.instrument_s,
        "indents": result.indents,
        # fast indents the instrument made (measured or failed), and their share of the indents above
        "fast_indents": 0 if campaign.fast is None else campaign.fast.n + campaign.fast.failed,
        "blocks": result.blocks,
        "reconfigurations": result.ledger.reconfigurations,
        "ledger": result.ledger.as_dict(),
        "final_mape_pct": score.mape_pct,
        "final_mape_modulus_pct": evaluator.score_modulus(campaign),
        "map_weights": settings_to_dict(campaign.settings)["map_weights"],
        "max_found_gpa": score.max_found_gpa,
        # the scoring lattice's cell centres miss the corners, where a field's maximum may sit
        "true_max_gpa": max(float(evaluator.truth_gpa.max()), field_extrema(evaluator.truth)[1]),
        "grid_baseline_s": campaign.grid_baseline_s,
        "stop_reason": result.stop_reason,
        "interlock_refusals": result.refusals,
        "wall_s": time.monotonic() - start,
        **calendar_keys,
        "trajectory": trajectory,
        "trajectory_modulus": [{"t_s": t, "mape_pct": m} for t, m in modulus],
        "_ledger_obj": result.ledger,
    }


def _handler(args: argparse.Namespace) -> int:
    out = run_simulation(
        policy=args.policy,
        seed=args.seed,
        scenario=args.scenario,
        truth=args.truth,
        noise=args.noise,
        drift=args.drift,
        budget_s=args.budget_s,
        lattice_n=args.lattice_n,
        profile=args.profile,
        sample_file=args.sample,
        failure_rate=args.failure_rate,
        progress=not args.json and sys.stderr.isatty(),
        map_weights=args.map_weights,
        calendar=operator_calendar(args),
        fast=args.fast == "on",
    )
    ledger = out.pop("_ledger_obj")
    if args.json:
        print(dumps(out))
        return 0
    print(f"policy {out['policy']} on {out['scenario']} (seed {out['seed']}, profile {out['profile']})")
    print(f"stopped: {out['stop_reason']}")
    print(
        f"instrument time {out['instrument_s']:,.0f} s ({out['instrument_s'] / 3600:.1f} h); "
        f"grid baseline {out['grid_baseline_s']:,.0f} s"
    )
    fast = f" ({out['fast_indents']} fast)" if out["fast_indents"] else ""
    print(
        f"{out['indents']} indents{fast} in {out['blocks']} blocks, {out['reconfigurations']} reconfigurations"
    )
    if "wall_clock_h" in out:
        print(
            f"wall clock {out['wall_clock_h']:.1f} h from {out['start']}, {out['operator_visits']} operator visits"
        )
    mape = out["final_mape_pct"]
    print(f"final MAPE {mape:.2f} %" if mape is not None else "final MAPE: no model")
    mape_e = out["final_mape_modulus_pct"]
    print(f"final modulus MAPE {mape_e:.2f} %" if mape_e is not None else "final modulus MAPE: no model")
    print(f"max hardness found {out['max_found_gpa']:.3f} GPa (true max {out['true_max_gpa']:.3f} GPa)")
    print(ledger_table(ledger))
    return 0


def register(sub: argparse._SubParsersAction) -> None:

    p = sub.add_parser("simulate", help="run one headless emulator campaign")
    p.add_argument("--policy", choices=policy_names(), default=RECOMMENDED)
    p.add_argument("--seed", type=seed_arg, default=0)
    p.add_argument("--scenario", default="ternary", help="emulator scenario (see `aeni scenarios`)")
    p.add_argument(
        "--truth",
        default=None,
        metavar="FILE.csv",
        help="ground truth CSV: x_um, y_um, hardness_gpa[, noise_sd_gpa]",
    )
    p.add_argument("--noise", choices=NOISE_CHOICES, default=None, help="noise scenario override")
    p.add_argument("--drift", choices=("none", "good", "bad"), default=None, help="drift scenario override")
    p.add_argument(
        "--budget-s",
        type=positive_float("--budget-s"),
        default=None,
        help="instrument-time budget (default: the grid baseline's time)",
    )
    p.add_argument("--lattice-n", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument("--profile", default=None, help="instrument profile name or TOML file")
    p.add_argument(
        "--sample", default=None, metavar="FILE", help="sample file to lay the scenario's truth onto"
    )
    p.add_argument(
        "--failure-rate",
        dest="failure_rate",
        type=float,
        default=None,
        help="share of indents the simulated instrument fails (invalid values; a quarter of it of the "
        "blocks find no surface or are aborted); default 0",
    )
    p.add_argument(
        "--map-weights",
        type=map_weights_arg,
        default=None,
        metavar="hardness=W,modulus=W",
        help="how much each map's relative error counts in the planner's aim (default hardness=1,modulus=1)",
    )
    p.add_argument(
        "--fast",
        choices=("off", "on"),
        default="off",
        help="on: the plan prices the profile's fast (NanoBlitz-class) arrays beside CSM indents, one "
        "two-fidelity model learns from both (docs/two-fidelity.md); off (default): CSM indents only",
    )
    add_operator_args(p)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=_handler)

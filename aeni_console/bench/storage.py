"""The bench's results.json: its runs written (thinned trajectories, no maps), read back, and several
parts merged into one."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from aeni_console.bench.catalogue import (
    EXTRA_SCENARIOS,
    FULL_SCENARIOS,
    MAX_CENTRES,
    QUICK_SCENARIOS,
    BenchConfig,
)
from aeni_console.bench.runner import RunRecord
from aeni_console.bench.statistics import policy_names_in_order, summarise
from core.errors import InputError

if TYPE_CHECKING:
    from core.visits import OperatorCalendar


def records_from_json(data: dict[str, Any]) -> tuple[list[RunRecord], BenchConfig, float]:
    """A bench's runs, configuration and wall time back from its results.json (maps are not stored there;
    trajectories are thinned): to render the report again without running the campaigns."""
    try:
        proto = data["protocol"]
        keys = ",".join(s["key"] for s in proto["scenarios"])
        config = BenchConfig.make(bool(proto["quick"]), int(proto["seeds"]), int(proto["jobs"]), only=keys)
        stored = {s["key"]: tuple(s["policies"]) for s in proto["scenarios"]}
        config = replace(
            config,
            scenarios=tuple(replace(sc, policies=stored[sc.key]) for sc in config.scenarios),
            lattice_n=int(proto["lattice_n"]),
            margin=float(proto["margin"]),
            max_blocks=int(proto["max_blocks"]),
            max_centres=int(proto.get("max_centres", MAX_CENTRES)),
            # results of the release before failures were on by default ran without them
            failure_rate=float(proto.get("failure_rate", 0.0)),
        )
        names = {f.name for f in fields(RunRecord)}
        records = []
        for run in data["runs"]:
            d = {k: v for k, v in run.items() if k in names}
            d["trajectory"] = [(float(t), float(m)) for t, m in d["trajectory"]]
            d["max_found"] = [(float(t), float(v)) for t, v in d["max_found"]]
            d["grid_sizes"] = {int(k): int(v) for k, v in d.get("grid_sizes", {}).items()}
            d["ledger"] = {str(k): float(v) for k, v in d["ledger"].items()}
            d["trajectory_modulus"] = [(float(t), float(m)) for t, m in d.get("trajectory_modulus", [])]
            if "fast_indents" not in run:  # results written before the fast column was recorded
                # a policy without the +fast modifier plans no fast arrays: its 0 is known; one with it is not
                known = "fast" not in str(run["policy"]).split("+")[1:]
                d["fast_indents"], d["fast_array_s"] = (0, 0.0) if known else (None, None)
            records.append(RunRecord(**d))
        return records, config, float(proto["wall_s"])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(
            "results.json", f"not the output of aeni bench ({type(exc).__name__}: {exc})"
        ) from None


def merge_results(
    parts: Sequence[tuple[list[RunRecord], BenchConfig, float]],
) -> tuple[list[RunRecord], BenchConfig, float]:
    """Several bench runs as one (``aeni bench --render-from a.json,b.json``): a sweep run in pieces, or one
    policy run again after a change. A run of the same scenario, policy and seed in a later part replaces the
    earlier one. The parts must share the protocol and, where they overlap, the grid baselines (which set every
    target): otherwise they were not run on the same emulator and cannot be compared."""
    if not parts:
        raise InputError("--render-from", "no results to merge")
    first = parts[0][1]
    keep = ("quick", "lattice_n", "margin", "failure_rate")
    caps: dict[str, Any] = {
        "max_blocks": max(c.max_blocks for _, c, _ in parts),
        "max_centres": max(c.max_centres for _, c, _ in parts),
    }
    runs: dict[tuple[str, str, int], RunRecord] = {}
    policies: dict[str, list[str]] = {}
    for i, (records, config, _) in enumerate(parts):
        for name in keep:
            if getattr(config, name) != getattr(first, name):
                raise InputError(
                    "--render-from",
                    f"part {i + 1} was run with {name} = {getattr(config, name)}, part 1 with"
                    f" {getattr(first, name)}: runs under different protocols cannot be merged",
                )
        for r in records:
            # a lower cap is the same protocol for every run it did not stop
            if ("block cap" in r.stop_reason and config.max_blocks < caps["max_blocks"]) or (
                "centre cap" in r.stop_reason and config.max_centres < caps["max_centres"]
            ):
                raise InputError(
                    "--render-from",
                    f"part {i + 1}: {r.policy} on {r.scenario} seed {r.seed} stopped at a cap another part"
                    " raised: run it again under the higher cap",
                )
        for sc in config.scenarios:
            have = policies.setdefault(sc.key, [])
            have += [p for p in sc.policies if p not in have]
        for r in records:
            old = runs.get((r.scenario, r.policy, r.seed))
            if (
                r.policy == "grid"
                and old is not None
                and old.final_mape_pct is not None
                and r.final_mape_pct is not None
                and abs(old.final_mape_pct - r.final_mape_pct) > 1e-4
            ):
                raise InputError(
                    "--render-from",
                    f"part {i + 1}: the grid baseline of {r.scenario} seed {r.seed} ends at"
                    f" {r.final_mape_pct:.4f} % against {old.final_mape_pct:.4f} % before: not the same emulator",
                )
            runs[(r.scenario, r.policy, r.seed)] = r
    known = {s.key: s for s in (QUICK_SCENARIOS if first.quick else (*FULL_SCENARIOS, *EXTRA_SCENARIOS))}
    scen_keys = [k for k in (s.key for s in (*FULL_SCENARIOS, *EXTRA_SCENARIOS)) if k in policies]
    scen_keys += [k for k in policies if k not in scen_keys]
    order = policy_names_in_order([p for k in scen_keys for p in policies[k]])
    scenarios = tuple(
        replace(known[k], policies=tuple(p for p in order if p in policies[k])) for k in scen_keys
    )
    config = replace(
        first,
        seeds=max(c.seeds for _, c, _ in parts),
        jobs=max(c.jobs for _, c, _ in parts),
        scenarios=scenarios,
        **caps,
    )
    records = sorted(runs.values(), key=lambda r: (scen_keys.index(r.scenario), r.policy != "grid", r.seed))
    return records, config, sum(w for _, _, w in parts)


def _thin(
    points: Sequence[tuple[float, float]], keep_t: float | None, most: int = 120
) -> list[tuple[float, float]]:
    """About ``most`` points, evenly by index, always with the first, the last, the hit and every new lowest
    MAPE: the time a run first reached any error level stays exact (a report rendered from the file)."""
    if len(points) <= most:
        return list(points)
    idx = set(np.linspace(0, len(points) - 1, most).astype(int).tolist())
    idx |= {i for i, p in enumerate(points) if keep_t is not None and p[0] == keep_t}
    best = math.inf
    for i, (_, m) in enumerate(points):
        if m < best:
            best = m
            idx.add(i)
    return [points[i] for i in sorted(idx)]


def _calendar_json(calendar: OperatorCalendar) -> dict[str, Any]:
    a = calendar.availability
    return {
        "operator_hours": a.hours.text,
        "response_min": a.response_s / 60.0,
        "visit_every_min": a.visit_every_s / 60.0,
        "start": calendar.start.isoformat(timespec="minutes"),
    }


def records_to_json(records: Sequence[RunRecord], config: BenchConfig, wall_s: float) -> dict[str, Any]:
    """results.json: the protocol, every run (without maps) and the summaries."""

    def clean(obj: Any) -> Any:
        if isinstance(obj, float):
            return None if not math.isfinite(obj) else round(obj, 6)
        if isinstance(obj, dict):
            return {str(k): clean(v) for k, v in obj.items()}
        if isinstance(obj, list | tuple):
            return [clean(v) for v in obj]
        return obj

    runs = []
    for r in records:
        d = asdict(replace(r, maps=None))
        d.pop("maps")
        for key in ("wall_clock_h", "operator_visits", "wall_clock_both_h", "operator_visits_both"):
            if d[key] is None:
                d.pop(key)  # a bench without a calendar writes the file it always wrote
        # MAPE to 1e-6 %: a report rendered again from this file finds the same looser-target times
        d["trajectory"] = [[round(t, 3), round(m, 6)] for t, m in _thin(r.trajectory, r.t_hit_s)]
        steps = [p for i, p in enumerate(r.max_found) if i == 0 or p[1] != r.max_found[i - 1][1]]
        d["max_found"] = [[round(t), round(v, 4)] for t, v in steps]  # only where it rose
        if r.trajectory_modulus or r.final_mape_modulus_pct is not None:
            d["trajectory_modulus"] = [
                [round(t, 3), round(m, 6)] for t, m in _thin(r.trajectory_modulus, r.t_hit_modulus_s)
            ]
        else:  # hardness only: results.json as before issue 27
            for key in (
                "target_mape_modulus_pct",
                "final_mape_modulus_pct",
                "t_hit_modulus_s",
                "trajectory_modulus",
            ):
                d.pop(key)
        runs.append(d)
    return clean(
        {
            "protocol": {
                "quick": config.quick,
                "seeds": config.seeds,
                "jobs": config.jobs,
                "lattice_n": config.lattice_n,
                "margin": config.margin,
                "max_blocks": config.max_blocks,
                "max_centres": config.max_centres,
                "failure_rate": config.failure_rate,
                "scenarios": [
                    {"key": s.key, "scenario": s.scenario, "title": s.title, "policies": list(s.policies)}
                    for s in config.scenarios
                ],
                "wall_s": wall_s,
                **({"calendar": _calendar_json(config.calendar)} if config.calendar is not None else {}),
            },
            "summaries": [asdict(s) for s in summarise(records)],
            "runs": runs,
        }
    )

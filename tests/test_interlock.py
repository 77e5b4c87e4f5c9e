"""The safety interlock: its own geometry refuses every unsafe block, on any sample, from any planner.

The oracle below re-checks each rule with other code (core.geometry's edge distances and plane, the
sample model's even-odd polygon test, scipy's k-d tree): whatever the interlock lets through must pass
the oracle, and whatever it refuses must break a rule.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from core.errors import InputError
from core.geometry import Calibration, Corner
from core.interlock import MIN_OWN_PITCH_UM, SAFETY_HOP_UM, Interlock
from core.journal import Journal, JournalReader, send_command
from core.plan import Block, Decision, IndentResult, IndentSpec, PlannerSettings, local_grid
from core.profile import InstrumentProfile, load_profile
from core.run.engine import Engine
from core.runview import Command, CommandKind, EngineState, MapFields
from core.sample import CircleExclusion, PolygonExclusion, Sample

PROFILE = load_profile("kla-imicro")
# a user-fitted profile that reconfigures only from 1500 µm: hops of 1000–1500 µm must be refused
LAX_PROFILE = dataclasses.replace(PROFILE, name="lax", reconfig_threshold_um=1500.0)


# ---------------------------------------------------------------------------------------------- oracle


def violations(
    sample: Sample,
    profile: InstrumentProfile,
    block: Block,
    position: tuple[float, float],
    earlier: np.ndarray,
    program_centre: tuple[float, float] | None,
    tol: float,
) -> list[str]:
    """Every rule the block breaks by more than ``tol`` µm (tol < 0: also those it nearly breaks)."""
    xy = np.array([(s.x_um, s.y_um) for s in block.indents], dtype=float).reshape(-1, 2)
    out: list[str] = []
    if len(xy) == 0:
        return ["empty"]
    if not np.all(np.isfinite(xy)):
        return ["non-finite"]
    x0, y0, x1, y1 = sample.stage_rect_um
    if ((xy[:, 0] < x0 - tol) | (xy[:, 0] > x1 + tol) | (xy[:, 1] < y0 - tol) | (xy[:, 1] > y1 + tol)).any():
        out.append("stage")
    cal = sample.calibration
    if (cal.edge_distance_um(xy[:, 0], xy[:, 1]) < sample.edge_band_um - tol).any():
        out.append("edge")
    for region in sample.exclusions:
        if isinstance(region, CircleExclusion):
            if (np.hypot(xy[:, 0] - region.x_um, xy[:, 1] - region.y_um) < region.radius_um + tol).any():
                out.append("exclusion")
        elif (region.clearance_um(xy[:, 0], xy[:, 1]) < tol).any():
            out.append("exclusion")
    if len(xy) > 1:
        d, _ = cKDTree(xy).query(xy, k=2)
        if (d[:, 1] < MIN_OWN_PITCH_UM - tol).any():
            out.append("pitch")
    if len(earlier) and sample.r_excl_um > 0:
        d, _ = cKDTree(earlier).query(xy, k=1)
        if (d < sample.r_excl_um - tol).any():
            out.append("r_excl")
    centre = (block.center_x_um, block.center_y_um) if block.kind == "global" else program_centre
    if centre is None:
        out.append("no program")
    else:
        dz = np.abs(cal.plane.z_um(xy[:, 0], xy[:, 1]) - cal.plane.z_um(*centre))
        if (dz > sample.dz_safe_um + tol).any():
            out.append("band")
    path = xy if block.kind == "global" else np.vstack([position, xy])
    for (ax, ay), (bx, by) in itertools.pairwise(path):
        dx, dy = abs(bx - ax), abs(by - ay)
        if max(dx, dy) >= SAFETY_HOP_UM - min(tol, 0.0) and not profile.needs_reconfiguration(dx, dy):
            out.append("hop")
            break
    return out


# ---------------------------------------------------------------------------------------------- samples


@st.composite
def samples(draw: st.DrawFn) -> Sample:
    """Rotated, skewed, tilted corner sets with exclusions, earlier indents and sometimes a tight stage."""
    cx = draw(st.floats(2_000.0, 90_000.0))
    cy = draw(st.floats(2_000.0, 90_000.0))
    w = draw(st.floats(300.0, 6_000.0))
    h = draw(st.floats(300.0, 6_000.0))
    theta = math.radians(draw(st.floats(-40.0, 40.0)))
    skew = draw(st.lists(st.floats(-0.08, 0.08), min_size=8, max_size=8))
    a = draw(st.floats(-0.02, 0.02))
    b = draw(st.floats(-0.02, 0.02))
    zn = draw(st.lists(st.floats(-2.0, 2.0), min_size=4, max_size=4))
    base = [(-w / 2, h / 2), (w / 2, h / 2), (w / 2, -h / 2), (-w / 2, -h / 2)]
    c, s = math.cos(theta), math.sin(theta)
    corners = []
    for k, (px, py) in enumerate(base):
        px += skew[2 * k] * w
        py += skew[2 * k + 1] * h
        x, y = cx + c * px - s * py, cy + s * px + c * py
        corners.append(Corner(x, y, 200.0 + a * (x - cx) + b * (y - cy) + zn[k]))
    try:
        cal = Calibration.from_corners(*corners)
    except InputError:
        assume(False)
        raise
    x_min, x_max, y_min, y_max = cal.bounds_um
    span = max(x_max - x_min, y_max - y_min)

    def point(margin: float = 0.2) -> tuple[float, float]:
        u = draw(st.floats(-margin, 1 + margin))
        v = draw(st.floats(-margin, 1 + margin))
        return (x_min + u * (x_max - x_min), y_min + v * (y_max - y_min))

    exclusions: list[CircleExclusion | PolygonExclusion] = []
    for _ in range(draw(st.integers(0, 3))):
        if draw(st.booleans()):
            px, py = point()
            exclusions.append(CircleExclusion(px, py, draw(st.floats(5.0, 0.3 * span))))
        else:
            verts = tuple(point() for _ in range(draw(st.integers(3, 6))))
            exclusions.append(PolygonExclusion(verts))
    earlier = tuple(point(0.0) for _ in range(draw(st.integers(0, 25))))
    if draw(st.booleans()):
        stage = (
            x_min - 50.0,
            y_min - 50.0,
            x_max + 50.0,
            y_max - draw(st.floats(0.0, 0.5)) * (y_max - y_min),
        )
    else:
        stage = (0.0, 0.0, 100_000.0, 100_000.0)
    return Sample(
        name="generated",
        profile="kla-imicro",
        calibration=cal,
        lattice_n=20,
        dz_safe_um=draw(st.floats(0.5, 10.0)),
        r_excl_um=draw(st.floats(0.0, 40.0)),
        edge_band_um=draw(st.floats(0.0, 60.0)),
        stage_rect_um=stage,
        exclusions=tuple(exclusions),
        earlier_indents_um=earlier,
    )


def adversarial_block(
    rng: np.random.Generator, sample: Sample, block_id: int, ran: np.ndarray
) -> tuple[Block, tuple[float, float], bool]:
    """Planner output gone wrong: grids near edges, exclusions, earlier indents and its own last indents
    (``ran``), odd pitches, far hops, stray sites, local blocks without a program (seeded numpy draws:
    cheap enough for thousands)."""
    x_min, x_max, y_min, y_max = sample.calibration.bounds_um
    anchors = [
        (r.x_um, r.y_um) if isinstance(r, CircleExclusion) else r.vertices_um[0] for r in sample.exclusions
    ]
    anchors += list(sample.earlier_indents_um[:5]) + [(c.x_um, c.y_um) for c in sample.calibration.corners]
    anchors += [tuple(p) for p in ran[-5:]]
    pick = rng.random()
    if pick < 0.4:  # somewhere on the sample
        u, v = sample.calibration.to_stage(rng.uniform(0.1, 0.9), rng.uniform(0.1, 0.9))
        cx, cy = float(u), float(v)
    elif pick < 0.7:  # close to something to keep away from
        ax, ay = anchors[rng.integers(len(anchors))]
        cx, cy = ax + rng.uniform(-60.0, 60.0), ay + rng.uniform(-60.0, 60.0)
    else:
        cx = x_min + rng.uniform(-0.1, 1.1) * (x_max - x_min)
        cy = y_min + rng.uniform(-0.1, 1.1) * (y_max - y_min)
    g = int(rng.integers(1, 6))
    pitch = float(rng.choice([5.0] * 8 + [2.5, 30.0, 700.0, 1200.0]))
    hold = float(rng.choice(PROFILE.allowed_holds_s))
    sites = list(local_grid(cx, cy, g, pitch, hold))
    if rng.random() < 0.1:  # one stray site anywhere
        k = int(rng.integers(len(sites)))
        sx = x_min + rng.uniform(-0.5, 1.5) * (x_max - x_min)
        sy = y_min + rng.uniform(-0.5, 1.5) * (y_max - y_min)
        sites[k] = IndentSpec(sx, sy, hold)
    kind = "global" if rng.random() < 0.5 else "local"
    block = Block(block_id, kind, cx, cy, g, pitch, hold, tuple(sites))  # type: ignore[arg-type]
    reach = 1600.0 if rng.random() < 0.5 else 60.0
    position = (cx + rng.uniform(-reach, reach), cy + rng.uniform(-reach, reach))
    return block, position, bool(rng.random() < 0.5)


BLOCKS_PER_SAMPLE = 25
N_SAMPLES = 400  # 400 samples × 25 blocks: 10,400 generated samples and blocks


@settings(max_examples=N_SAMPLES, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(sample=samples(), lax=st.booleans(), seed=st.integers(0, 2**32 - 1))
def test_no_refused_condition_ever_reaches_a_driver(sample: Sample, lax: bool, seed: int) -> None:
    profile = LAX_PROFILE if lax else PROFILE
    lock = Interlock(sample, profile)
    earlier = sample.earlier_xy_um
    centre: tuple[float, float] | None = None
    rng = np.random.default_rng(seed)
    for block_id in range(BLOCKS_PER_SAMPLE):
        block, position, program_open = adversarial_block(rng, sample, block_id, earlier)
        reason = lock.check(block, position, program_open)
        if reason is None:
            # let through: it must break no rule (up to rounding)
            assert violations(sample, profile, block, position, earlier, centre, tol=1e-5) == []
            # it runs: the instrument lands each indent within a micrometre of where it was sent
            results = [
                IndentResult(
                    block_id, i, s.x_um, s.y_um, s.x_um + dx, s.y_um + dy, s.hold_s, 5.0, 100.0, 0.0, 0.0
                )
                for i, (s, (dx, dy)) in enumerate(
                    zip(block.indents, rng.normal(0, 0.5, (block.n_indents, 2)), strict=True)
                )
            ]
            lock.passed(block, results)
            earlier = np.vstack([earlier, [(r.actual_x_um, r.actual_y_um) for r in results]])
            if block.kind == "global":
                centre = (block.center_x_um, block.center_y_um)
        else:
            # refused: it breaks (or within 0.1 µm nearly breaks) at least one rule, and says so in one line
            assert violations(sample, profile, block, position, earlier, centre, tol=-1e-4) != []
            assert "\n" not in reason and reason


# ---------------------------------------------------------------------------------------------- examples


def real_looking_sample(r_excl_um: float = 20.0) -> Sample:
    import tomllib

    from core.sample import SAMPLE_TEMPLATE, parse_sample

    data = tomllib.loads(SAMPLE_TEMPLATE)
    data["safety"]["r_excl_um"] = r_excl_um
    data["earlier"] = {"indents_um": [[12600.0, 8900.0], [12605.0, 8900.0]]}
    return parse_sample(data, "template")


def _grid(block_id: int, kind: str, x: float, y: float, g: int = 3) -> Block:
    return Block(block_id, kind, x, y, g, 5.0, 80.0, local_grid(x, y, g, 5.0, 80.0))  # type: ignore[arg-type]


def test_each_rule_refuses_with_its_reason() -> None:
    s = real_looking_sample()
    lock = Interlock(s, PROFILE)
    here = (12700.0, 8400.0)
    assert lock.check(_grid(0, "global", 12900.0, 8400.0), here, False) is None
    assert "outside the corners" in (lock.check(_grid(0, "global", 11900.0, 8400.0), here, False) or "")
    assert "from the edge" in (lock.check(_grid(0, "global", 13000.0, 8060.0), here, False) or "")
    assert "inside exclusion region 0" in (lock.check(_grid(0, "global", 12700.0, 8650.0), here, False) or "")
    assert "inside exclusion region 1" in (lock.check(_grid(0, "global", 12100.0, 8100.0), here, False) or "")
    assert "earlier indent" in (lock.check(_grid(0, "global", 12610.0, 8905.0), here, False) or "")
    assert "no program open" in (lock.check(_grid(0, "local", 12900.0, 8400.0), here, True) or "")
    tight = Interlock(dataclasses.replace(s, stage_rect_um=(0.0, 0.0, 12800.0, 100_000.0)), PROFILE)
    assert "safe travel" in (tight.check(_grid(0, "global", 12900.0, 8400.0), here, False) or "")
    # a block's own sites keep the method's pitch; closer ones are refused
    squeezed = Block(0, "global", 12900.0, 8400.0, 2, 1.0, 80.0, local_grid(12900.0, 8400.0, 2, 1.0, 80.0))
    assert "apart" in (lock.check(squeezed, here, False) or "")


def test_indents_of_passed_blocks_and_the_program_centre_are_remembered() -> None:
    s = real_looking_sample()
    lock = Interlock(s, PROFILE)
    first = _grid(0, "global", 12900.0, 8400.0)
    results = [
        IndentResult(0, i, p.x_um, p.y_um, p.x_um, p.y_um, 80.0, 5.0, 100.0, 0.0, 0.0)
        for i, p in enumerate(first.indents)
    ]
    lock.passed(first, results)
    assert lock.program_centre_um == (12900.0, 8400.0)
    again = _grid(1, "local", 12910.0, 8400.0)
    assert "earlier indent" in (lock.check(again, (12905.0, 8405.0), True) or "")
    assert lock.check(_grid(1, "local", 12960.0, 8400.0), (12905.0, 8405.0), True) is None
    # out of the safe band of the program's centre: the plane rises ~2 µm/mm here, dz_safe is 5 µm
    far = _grid(1, "local", 13300.0, 8950.0)
    reason = lock.check(far, (12905.0, 8405.0), True)
    assert reason is None or "safe band" in reason
    narrow = Interlock(dataclasses.replace(s, dz_safe_um=0.2), PROFILE)
    narrow.restore([(first, results)])
    assert "safe band" in (narrow.check(far, (12905.0, 8405.0), True) or "")


def test_a_far_engaged_hop_needs_a_reconfiguration() -> None:
    s = dataclasses.replace(real_looking_sample(), exclusions=(), dz_safe_um=50.0)
    start = _grid(0, "global", 12100.0, 8600.0)
    res = [
        IndentResult(0, i, p.x_um, p.y_um, p.x_um, p.y_um, 80.0, 5.0, 100.0, 0.0, 0.0)
        for i, p in enumerate(start.indents)
    ]
    hop = _grid(1, "local", 13250.0, 8600.0)
    for profile, refused in ((PROFILE, False), (LAX_PROFILE, True)):
        lock = Interlock(s, profile)
        lock.passed(start, res)
        reason = lock.check(hop, (12105.0, 8605.0), True)
        assert (reason is not None and "without a reconfiguration" in reason) == refused


# ---------------------------------------------------------------------------------------------- through the engine


class AdversarialCampaign:
    """A planner gone wrong: proposes seeded random blocks, many of them unsafe; vetoes move it on."""

    def __init__(self, sample: Sample, n_blocks: int, seed: int) -> None:
        self.sample = sample
        self.settings = PlannerSettings()
        self.rng = np.random.default_rng(seed)
        self.n_blocks = n_blocks
        self.observed: list[tuple[Block, list[IndentResult]]] = []
        self.offered = 0
        self.calibration = sample.calibration
        self.last_stop_reason: str | None = None

    def propose(
        self, clock_s: float, position_um: tuple[float, float], program_open: bool, block_id: int
    ) -> Decision | None:
        if len(self.observed) >= self.n_blocks or self.offered > 200:
            return None
        self.offered += 1
        x0, x1, y0, y1 = self.sample.calibration.bounds_um
        x = x0 + self.rng.uniform(-0.1, 1.1) * (x1 - x0)
        y = y0 + self.rng.uniform(-0.1, 1.1) * (y1 - y0)
        kind = "global" if not program_open or self.rng.random() < 0.4 else "local"
        block = Block(block_id, kind, x, y, 2, 5.0, 80.0, local_grid(x, y, 2, 5.0, 80.0))  # type: ignore[arg-type]
        return Decision(block=block, policy="adversary", acquisition=1.0, score=1.0, predicted_cost_s=600.0)

    def veto(self, decision: Decision, hold_blocks: int = 3) -> None:
        pass

    def adjust(self, **changes: Any) -> PlannerSettings:
        return self.settings

    def observe_block(self, block: Block, results: Sequence[IndentResult]) -> None:
        self.observed.append((block, list(results)))

    def map_fields(self, snapshot_id: int, display_n: int = 50) -> MapFields:
        xs = np.linspace(0.0, 1.0, 2)
        z = np.zeros((2, 2))
        return MapFields(snapshot_id, xs, xs, z, z, z, z)

    def export_state(self) -> dict[str, Any]:
        return {"n": len(self.observed)}

    def restore(self, state: dict[str, Any], blocks: Sequence[tuple[Block, Sequence[IndentResult]]]) -> None:
        self.observed = [(b, list(r)) for b, r in blocks]


class RecordingDriver:
    """The simulated instrument, noting every block it is handed (what reached a driver)."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.profile = inner.profile
        self.received: list[tuple[Block, tuple[float, float], bool]] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def execute_block(self, block: Block, start_index: int = 0) -> Any:
        self.received.append((block, self.inner.position_um(), self.inner.program_open()))
        return self.inner.execute_block(block, start_index)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("supervision", ["supervised", "auto"])
def test_refused_blocks_never_reach_the_driver_and_never_stall_the_run(
    tmp_path: Path, seed: int, supervision: str
) -> None:
    """Supervised: the operator vetoes what the interlock holds back. Auto: the engine vetoes it itself."""
    from drivers.sim.scenarios import make_scenario

    sample = real_looking_sample()
    campaign = AdversarialCampaign(sample, n_blocks=6, seed=seed)
    driver = RecordingDriver(make_scenario("ternary", seed).on_sample(sample).make_driver(PROFILE))
    journal = Journal.create(tmp_path / "run.sqlite", {"name": "adv"}, PROFILE, {}, name="adv")
    path = journal.path
    refusals: list[str] = []

    def operator(_s: float) -> None:
        # the operator vetoes whatever the interlock holds back, approves the rest
        if eng.state == EngineState.AWAITING_APPROVAL and eng._pending is not None:
            why = eng._pending[2]
            if why.startswith("safety interlock"):
                refusals.append(why)
            kind = CommandKind.VETO if why.startswith("safety interlock") else CommandKind.APPROVE
            send_command(path, Command(kind, author="op"))

    eng = Engine(
        journal,
        campaign,
        driver,
        supervision,
        poll_s=0.01,
        sleep=operator,
        watch_s=None,
        interlock=Interlock(sample, PROFILE),
        max_refusals=1000,  # the adversary proposes at random: many refusals in a row are expected
    )
    try:
        assert eng.run() == EngineState.STOPPED
    finally:
        journal.close()
    with JournalReader(path) as r:
        refused = [d for d in r.decisions() if d.needs_approval_reason.startswith("safety interlock")]
    if supervision == "auto":
        refusals = [d.needs_approval_reason for d in refused]
    assert refusals and all(r.startswith("safety interlock refused block") for r in refusals)
    assert all(d.status == "vetoed" for d in refused)  # none ran, none waits
    earlier = sample.earlier_xy_um
    centre = None
    for block, pos, _open in driver.received:
        assert violations(sample, PROFILE, block, pos, earlier, centre, tol=1e-5) == []
        res = [r for b, rs in campaign.observed if b.block_id == block.block_id for r in rs]
        earlier = np.vstack([earlier, [(r.actual_x_um, r.actual_y_um) for r in res]])
        if block.kind == "global":
            centre = (block.center_x_um, block.center_y_um)
    with JournalReader(path) as r:
        logged = [e for e in r.table("events")[1] if "safety interlock refused" in str(e)]
    assert len(logged) >= len(refusals)


def test_a_polygon_traced_twice_or_crossing_itself_is_inside_for_planner_and_interlock() -> None:
    tri = ((0.0, 0.0), (100.0, 0.0), (0.0, 100.0))
    twice = PolygonExclusion(tri + tri)
    bow = PolygonExclusion(((0.0, 0.0), (100.0, 100.0), (100.0, 0.0), (0.0, 100.0)))  # a bow tie
    pts = np.array([[20.0, 10.0], [80.0, 50.0], [20.0, 50.0], [200.0, 200.0]])
    assert (twice.clearance_um(pts[:, 0], pts[:, 1]) < 0).tolist() == [True, False, True, False]
    assert (bow.clearance_um(pts[:, 0], pts[:, 1]) < 0).tolist() == [False, True, True, False]
    from core.interlock import _in_or_on_polygon

    assert _in_or_on_polygon(np.asarray(twice.vertices_um), pts).tolist() == [True, False, True, False]
    assert _in_or_on_polygon(np.asarray(bow.vertices_um), pts).tolist() == [False, True, True, False]

"""One home for the planner settings' rules: the run file, `aeni send adjust`, the engine and the codec
agree on every field, and the allowed holds are the instrument profile's."""

from __future__ import annotations

import math
import sqlite3
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aeni_console.cli.main import main as cli_main
from core.campaign import Campaign
from core.errors import InputError
from core.journal import Journal
from core.plan import PlannerSettings
from core.profile import load_profile
from core.runconfig import PlannerSection, make_campaign_config, parse_run_config
from core.settings import (
    ADJUSTABLE,
    RULES,
    STOP_RULES,
    adjust_settings,
    check_adjust,
    coerce_setting,
    settings_from_dict,
    settings_to_dict,
)
from drivers.sim.scenarios import make_scenario

HOLDS = load_profile("kla-imicro").allowed_holds_s  # 0, 5, 80 s

# (field, a bad value, what the message says is allowed): the same words wherever the value comes from
BAD: list[tuple[str, Any, str]] = [
    ("target_sem_gpa", 0, "a number > 0 (GPa)"),
    ("beta", -1, "a number ≥ 0"),
    ("hold_policy", "sometimes", "fixed or adaptive"),
    ("local_center_limit", 21, "a whole number from 0 to 20"),
    ("local_center_limit", 2.5, "a whole number from 0 to 20"),
    ("edge_penalty", 0.96, "a number from 0 to 0.95"),
    ("budget_s", -5, "a number > 0 (s) or empty"),
    ("indent_budget", 0, "a whole number ≥ 1 or empty"),
    ("mape_target_pct", "x", "a number > 0 (%) or empty"),
    ("beta", math.inf, "a number ≥ 0"),
    ("beta", True, "a number ≥ 0"),
    ("stop_at", "8 am", 'a local time "HH:MM" (24 h) or empty'),
    ("stop_at", "24:00", 'a local time "HH:MM" (24 h) or empty'),
    ("stop_at", 8, 'a local time "HH:MM" (24 h) or empty'),
    ("stop_rel_sd_pct", 0, "a number from 0 to 100 (%) or empty"),
    ("stop_rel_sd_pct", 150, "a number from 0 to 100 (%) or empty"),
]


def test_every_planner_setting_has_exactly_one_rule() -> None:
    tables = {"avoid_centers_um", "map_weights"}  # run-file tables with a codec of their own
    fields = set(PlannerSettings.__dataclass_fields__) - tables
    assert set(ADJUSTABLE) == fields and len(RULES) + len(STOP_RULES) == len(fields)
    # the run file's [planner] table names the same fields (its values go through the same rules)
    assert set(PlannerSection.model_fields) == fields | tables


@pytest.mark.parametrize(("name", "value", "allowed"), BAD)
def test_the_run_file_and_an_adjust_reject_a_value_with_the_same_words(
    name: str, value: Any, allowed: str
) -> None:
    with pytest.raises(InputError) as adjust:
        check_adjust({name: value}, HOLDS)
    assert str(adjust.value) == f"{name}: {value!r} is not allowed: expected {allowed}"
    with pytest.raises(InputError) as runfile:
        parse_run_config({"planner": {name: value}}, "run.toml")
    assert f"field planner.{name} = {value!r} is not allowed: expected {allowed}" in str(runfile.value)


def test_holds_are_the_profiles_wherever_the_profile_is_known() -> None:
    assert coerce_setting("fixed_hold_s", "5", HOLDS) == 5.0  # text from the form or a flag
    with pytest.raises(InputError, match=r"fixed_hold_s: 7 is not allowed: expected one of 0, 5, 80 s"):
        check_adjust({"fixed_hold_s": 7}, HOLDS)
    # the run file does not know the profile yet (it may come from the scenario): the campaign checks
    config = make_campaign_config(lattice_n=8, policy="cost-aware", settings={"fixed_hold_s": 7})
    assert config.settings.fixed_hold_s == 7.0
    with pytest.raises(
        InputError, match=r"^planner\.fixed_hold_s: 7\.0 is not allowed: expected one of 0, 5, 80"
    ):
        Campaign(config, make_scenario("ternary", 0).sample)


def test_the_default_hold_is_the_profiles() -> None:
    assert PlannerSettings().fixed_hold_s is None
    campaign = Campaign(make_campaign_config(lattice_n=8), make_scenario("ternary", 0).sample)
    assert campaign.settings.fixed_hold_s == campaign.profile.default_hold_s == 80.0
    assert campaign.profile.fast_hold_s == 5.0


def test_adjust_accepts_supervision_and_clean_values() -> None:
    clean = check_adjust({"beta": "2.5", "indent_budget": 40.0, "budget_s": "", "supervision": "step"}, HOLDS)
    assert clean == {"beta": 2.5, "indent_budget": 40, "budget_s": None, "supervision": "step"}
    with pytest.raises(InputError, match=r"^supervision: 'lazy' is not allowed"):
        check_adjust({"supervision": "lazy"}, HOLDS)
    with pytest.raises(InputError, match="nothing to adjust"):
        check_adjust({}, HOLDS)
    with pytest.raises(InputError, match=r"^avoid_centers_um: is not an adjustable setting"):
        adjust_settings(PlannerSettings(), {"avoid_centers_um": []}, HOLDS)


values = st.fixed_dictionaries(
    {},
    optional={
        "target_sem_gpa": st.floats(1e-4, 10),
        "beta": st.floats(0, 100),
        "hold_policy": st.sampled_from(["fixed", "adaptive"]),
        "fixed_hold_s": st.sampled_from(HOLDS),
        "local_center_limit": st.integers(0, 20),
        "edge_penalty": st.floats(0, 0.95),
        "budget_s": st.none() | st.floats(1, 1e7),
        "indent_budget": st.none() | st.integers(1, 10_000),
        "avoid_centers_um": st.lists(st.tuples(st.floats(-1e4, 1e4), st.floats(-1e4, 1e4)), max_size=3),
        "map_weights": st.fixed_dictionaries(
            {"hardness": st.floats(0.5, 10)}, optional={"modulus": st.floats(0, 10)}
        ),
    },
)


@settings(max_examples=60, deadline=None)
@given(data=values)
def test_the_codec_round_trips_what_the_run_file_accepts(data: dict[str, Any]) -> None:
    """What a run file holds, the journal writes and reads back unchanged (one codec for both)."""
    # cost-aware honours every hold setting (aeni refuses fixed ones: see the test below)
    from_file = parse_run_config({"campaign": {"policy": "cost-aware"}, "planner": data}).campaign.settings
    assert settings_from_dict(data) == from_file
    assert settings_from_dict(settings_to_dict(from_file)) == from_file


def test_the_codec_names_an_unknown_field() -> None:
    with pytest.raises(InputError, match=r"^betta: is not a planner setting \(allowed: target_sem_gpa"):
        settings_from_dict({"betta": 1})


def test_send_adjust_checks_before_queueing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "run.sqlite"
    Journal.create(path, {"name": "t"}, load_profile("kla-imicro"), name="t").close()
    assert cli_main(["send", str(path), "adjust", "edge_penalty=2"]) == 2
    err = capsys.readouterr().err.strip()
    assert (
        err.endswith("edge_penalty: 2 is not allowed: expected a number from 0 to 0.95") and "\n" not in err
    )
    assert cli_main(["send", str(path), "adjust", "fixed_hold_s=7"]) == 2
    assert "expected one of 0, 5, 80 s" in capsys.readouterr().err
    # a good value passes the rules and only then meets the next check (no engine runs this journal)
    assert cli_main(["send", str(path), "adjust", "edge_penalty=0.2"]) == 2
    assert "no engine is running" in capsys.readouterr().err
    with sqlite3.connect(path) as conn:
        assert conn.execute("SELECT COUNT(*) FROM commands").fetchone()[0] == 0


def test_hold_settings_a_policy_does_not_honour_are_refused_in_one_line() -> None:
    """Issue 24: ``hold_policy = "fixed"`` with ``fixed_hold_s = 80`` under aeni was ignored without a word."""
    data = {"campaign": {"policy": "aeni"}, "planner": {"hold_policy": "fixed", "fixed_hold_s": 80}}
    with pytest.raises(InputError) as info:
        parse_run_config(data, "night.toml")
    assert str(info.value).startswith("planner.hold_policy: 'fixed' is not honoured by policy 'aeni'")
    assert "\n" not in str(info.value)
    with pytest.raises(
        InputError, match=r"^planner\.fixed_hold_s: 5\.0 is not honoured by policy 'adaptive-hold'"
    ):
        parse_run_config({"campaign": {"policy": "adaptive-hold"}, "planner": {"fixed_hold_s": 5}})
    with pytest.raises(
        InputError, match=r"^planner\.hold_policy: 'adaptive' is not honoured by policy 'grid'"
    ):
        parse_run_config({"campaign": {"policy": "grid"}, "planner": {"hold_policy": "adaptive"}})
    # honoured: the policy's own hold, a fixed hold under a fixed-hold policy, either under cost-aware
    parse_run_config({"campaign": {"policy": "aeni"}, "planner": {"hold_policy": "adaptive"}})
    parse_run_config({"campaign": {"policy": "grid"}, "planner": {"fixed_hold_s": 5}})
    parse_run_config({"campaign": {"policy": "cost-aware"}, "planner": {"hold_policy": "adaptive"}})
    # the same rule for an adjust command, in the campaign (the engine's) and before it is queued
    campaign = Campaign(make_campaign_config(policy="aeni", lattice_n=8), make_scenario("ternary", 0).sample)
    with pytest.raises(InputError, match=r"^adjust\.fixed_hold_s: 5\.0 is not honoured"):
        campaign.adjust(fixed_hold_s=5.0)
    assert campaign.adjust(beta=2.0).beta == 2.0


async def test_the_adjust_form_shows_only_the_hold_settings_in_force() -> None:
    from textual.app import App
    from textual.widgets import Select

    from aeni_console.console.widgets.adjust import AdjustScreen

    for policy, fixed_shown, select_shown in (
        ("aeni", False, False),
        ("grid", True, False),
        ("cost-aware", True, True),
    ):
        app: App[None] = App()
        async with app.run_test() as pilot:
            screen = AdjustScreen(
                PlannerSettings(fixed_hold_s=80.0), allowed_holds_s=(0, 5, 80), policy=policy
            )
            app.push_screen(screen)
            await pilot.pause()
            assert bool(screen.query("#f-fixed_hold_s")) is fixed_shown, policy
            assert any(w.id == "f-hold_policy" for w in screen.query(Select)) is select_shown, policy
            changes, errors = screen.validate_form()
            assert changes == {} and errors == []


def test_map_weights_default_to_both_maps_and_refuse_bad_tables() -> None:
    from core.plan import MapWeights

    assert PlannerSettings().map_weights == MapWeights(1.0, 1.0)  # both maps by default (issue 37)
    both = parse_run_config({"planner": {"map_weights": {"hardness": 1.0, "modulus": 0.5}}}).campaign.settings
    assert both.map_weights == MapWeights(1.0, 0.5) and both.map_weights.maps_modulus
    only_e = settings_from_dict({"map_weights": {"hardness": 0, "modulus": 1}}).map_weights
    assert only_e == MapWeights(0.0, 1.0)
    for bad, words in (
        ({"hardness": 0, "modulus": 0}, "at least one map needs a weight > 0"),
        ({"hardness": -1}, r"map_weights.hardness: -1.0 is not allowed: expected a number ≥ 0"),
        ({"modulus": "lots"}, "planner.map_weights.modulus = 'lots' is not allowed: must be a valid number"),
        ({"stiffness": 1.0}, "unknown map.*'stiffness'.*known: hardness, modulus"),
        (1.0, "planner.map_weights = 1.0 is not allowed: must be a valid dictionary"),
    ):
        with pytest.raises(InputError, match=words):
            parse_run_config({"planner": {"map_weights": bad}})

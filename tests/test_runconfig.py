"""Run TOML files: defaults, a full file, and one clear message per bad field (field, value, what is allowed)."""

from __future__ import annotations

from pathlib import Path

import pytest

from core.errors import InputError
from core.runconfig import load_run_config, parse_run_config

FULL = """
name = "night-run"

[campaign]
policy = "uncertainty"
scenario = "ternary-good-drift"
noise = "homo"
drift = "bad"
seed = 7
profile = "kla-imicro"
lattice_n = 30

[planner]
target_sem_gpa = 0.08
beta = 2.0
hold_policy = "adaptive"
fixed_hold_s = 5
local_center_limit = 3
edge_penalty = 0.25
budget_s = 40000
indent_budget = 500
avoid_centers_um = [[100.0, 200.0]]

[run]
driver = "sim"
supervision = "supervised"
journal = "runs/night.sqlite"
speed = 50
"""


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "run.toml"
    p.write_text(text, encoding="utf-8")
    return p


def test_defaults_without_a_file() -> None:
    rc = load_run_config(None)
    from core.policies.registry import RECOMMENDED

    assert rc.campaign.policy == RECOMMENDED == "aeni"  # the recommended policy is the run file's default
    assert rc.campaign.driver_options == {"scenario": "ternary"} and rc.campaign.seed == 0
    assert rc.campaign.settings.budget_s is None and rc.campaign.name == "run"
    assert rc.options.supervision == "auto" and rc.options.driver == "sim" and rc.options.speed is None


def test_full_file(tmp_path: Path) -> None:
    rc = load_run_config(write(tmp_path, FULL))
    c, s, o = rc.campaign, rc.campaign.settings, rc.options
    assert (c.name, c.policy, c.seed, c.lattice_n, c.sample) == ("night-run", "uncertainty", 7, 30, None)
    assert c.driver_options == {"scenario": "ternary-good-drift", "noise": "homo", "drift": "bad"}
    assert (
        s.target_sem_gpa,
        s.beta,
        s.hold_policy,
        s.fixed_hold_s,
        s.local_center_limit,
        s.edge_penalty,
    ) == (0.08, 2.0, "adaptive", 5.0, 3, 0.25)
    assert s.budget_s == 40000 and s.indent_budget == 500 and s.avoid_centers_um == ((100.0, 200.0),)
    assert (o.supervision, o.journal, o.speed) == ("supervised", "runs/night.sqlite", 50.0)


def test_command_line_overrides_win_and_are_validated(tmp_path: Path) -> None:
    rc = load_run_config(
        write(tmp_path, FULL),
        {
            "campaign.seed": "11",
            "planner.budget_s": "2e4",
            "run.supervision": "step",
            "campaign.policy": None,
        },
    )
    assert (
        rc.campaign.seed == 11
        and rc.campaign.settings.budget_s == 20000.0
        and rc.options.supervision == "step"
    )
    assert rc.campaign.policy == "uncertainty"  # None leaves the file's value
    with pytest.raises(InputError, match=r"campaign\.seed = 'abc'"):
        load_run_config(None, {"campaign.seed": "abc"})


@pytest.mark.parametrize(
    ("text", "field", "value", "allowed"),
    [
        ('[campaign]\npolicy = "magic"', "campaign.policy", "'magic'", "cost-aware"),
        ("[campaign]\nseed = -1", "campaign.seed", "-1", "greater than or equal to 0"),
        ("[campaign]\nlattice_n = 2", "campaign.lattice_n", "2", "greater than or equal to 5"),
        ('[campaign]\nnoise = "loud"', "campaign.noise", "'loud'", "'hetero', 'homo' or '10pct'"),
        ("[planner]\nbeta = -0.5", "planner.beta", "-0.5", "expected a number ≥ 0"),
        ("[planner]\nedge_penalty = 2", "planner.edge_penalty", "2", "a number from 0 to 0.95"),
        ("[planner]\nbudget_s = 0", "planner.budget_s", "0", "a number > 0 (s) or empty"),
        (
            '[planner]\nhold_policy = "sometimes"',
            "planner.hold_policy",
            "'sometimes'",
            "fixed or adaptive",
        ),
        (
            "[planner]\nlocal_center_limit = 50",
            "planner.local_center_limit",
            "50",
            "a whole number from 0 to 20",
        ),
        ("[planner]\ntarget_sem_gpa = nan", "planner.target_sem_gpa", "nan", "a number > 0 (GPa)"),
        (
            "[planner]\nfixed_hold_s = -5",
            "planner.fixed_hold_s",
            "-5",
            "one of the instrument profile's holds",
        ),
        ('[run]\nsupervision = "lazy"', "run.supervision", "'lazy'", "expected auto, supervised, step"),
        ("[run]\nspeed = 0", "run.speed", "0", "greater than 0"),
        ('[run]\ndriver = "ftp"', "run.driver", "'ftp'", "'sim' or 'kla'"),
    ],
)
def test_each_bad_field_is_named_with_value_and_allowed(
    tmp_path: Path, text: str, field: str, value: str, allowed: str
) -> None:
    path = write(tmp_path, text)
    with pytest.raises(InputError) as info:
        load_run_config(path)
    msg = str(info.value)
    assert msg.startswith(str(path)) and "\n" not in msg
    assert f"field {field} = {value}" in msg and allowed in msg


def test_unknown_fields_and_sections_list_what_is_allowed(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"unknown field planner\.betta \(allowed: target_sem_gpa, beta"):
        load_run_config(write(tmp_path, "[planner]\nbetta = 1"))
    with pytest.raises(
        InputError,
        match=r"unknown field engine \(allowed: name, sample, campaign, planner, run, notify, operator\)",
    ):
        load_run_config(write(tmp_path, "[engine]\nx = 1"))


def test_all_bad_fields_are_reported_together(tmp_path: Path) -> None:
    with pytest.raises(InputError) as info:
        load_run_config(write(tmp_path, "[planner]\nbeta = -1\nedge_penalty = 5\n[run]\nspeed = -2"))
    msg = str(info.value)
    assert "planner.beta" in msg and "planner.edge_penalty" in msg and "run.speed" in msg


def test_bad_toml_and_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not valid TOML"):
        load_run_config(write(tmp_path, "[campaign\nseed = 1"))
    with pytest.raises(InputError, match="no such config file"):
        load_run_config(tmp_path / "nope.toml")


def test_csv_scenario_needs_a_truth_file_relative_to_the_config(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"campaign\.truth_csv is missing"):
        parse_run_config({"campaign": {"scenario": "csv"}})
    rc = load_run_config(write(tmp_path, '[campaign]\nscenario = "csv"\ntruth_csv = "truth.csv"'))
    assert rc.campaign.driver_options["truth_csv"] == str((tmp_path / "truth.csv").resolve())


def test_an_unknown_scenario_is_named_when_the_simulated_instrument_is_built() -> None:
    from drivers.registry import default_sample

    rc = load_run_config(None, {"campaign.scenario": "moon"})
    with pytest.raises(InputError) as info:
        default_sample("sim", rc.campaign.driver_options, 0)
    msg = str(info.value)
    assert msg.startswith("campaign.scenario: 'moon' is not allowed") and "ternary" in msg and "\n" not in msg


def test_the_sample_file_is_relative_to_the_run_file(tmp_path: Path) -> None:
    from core.sample import SAMPLE_TEMPLATE

    (tmp_path / "films").mkdir()
    (tmp_path / "films" / "s.toml").write_text(SAMPLE_TEMPLATE, encoding="utf-8")
    rc = load_run_config(write(tmp_path, '[sample]\nfile = "films/s.toml"'))
    assert rc.campaign.sample is not None and rc.campaign.sample.name == "NiTiCu-library-07"
    with pytest.raises(InputError, match="no such sample file"):
        load_run_config(write(tmp_path, '[sample]\nfile = "nope.toml"'))


def test_a_profile_file_is_relative_to_the_run_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from core.profile import load_profile

    (tmp_path / "lab").mkdir()
    (tmp_path / "lab" / "ours.toml").write_text('extends = "kla-imicro"\nname = "ours"\n', encoding="utf-8")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # the run file is read from another working directory
    rc = load_run_config(write(tmp_path, '[campaign]\nprofile = "lab/ours.toml"'))
    assert rc.campaign.profile == str((tmp_path / "lab" / "ours.toml").resolve())
    assert load_profile(rc.campaign.profile).name == "ours"
    # a built-in profile's name stays a name
    assert (
        load_run_config(write(tmp_path, '[campaign]\nprofile = "kla-imicro"')).campaign.profile
        == "kla-imicro"
    )


def test_run_section_holds_the_engines_no_wait_rules() -> None:
    o = parse_run_config({}).options
    assert (o.max_refusals, o.approval_timeout_s, o.on_timeout) == (5, None, "approve")
    o = parse_run_config({"run": {"max_refusals": 2, "approval_timeout_s": 60, "on_timeout": "veto"}}).options
    assert (o.max_refusals, o.approval_timeout_s, o.on_timeout) == (2, 60.0, "veto")
    for bad, field in (
        ({"max_refusals": 0}, "run.max_refusals"),
        ({"approval_timeout_s": -1}, "run.approval_timeout_s"),
        ({"on_timeout": "shrug"}, "run.on_timeout"),
    ):
        with pytest.raises(InputError, match=field.replace(".", r"\.")):
            parse_run_config({"run": bad})

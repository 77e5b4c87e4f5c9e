"""docs/config.md is generated from the validators and must be current (it cannot drift from them)."""

from __future__ import annotations

import re
import tomllib

from aeni_console.reports import configdoc
from core.runconfig import RunFile, parse_run_config


def test_config_doc_is_current() -> None:
    assert configdoc.DOC_PATH.read_text(encoding="utf-8") == configdoc.render(), (
        "docs/config.md is stale: run python -m aeni_console.reports.configdoc"
    )


def test_every_field_has_a_meaning_and_no_meaning_is_stale() -> None:
    rows = configdoc.field_rows(RunFile)
    names = {r[0] for r in rows}
    assert [r[0] for r in rows if not r[4]] == []
    assert set(configdoc.MEANINGS) <= names, set(configdoc.MEANINGS) - names


def test_the_doc_states_what_the_validator_enforces() -> None:
    rows = {r[0]: r for r in configdoc.field_rows(RunFile)}
    # the bounds are the validator's: the doc's limit is accepted, just past it is refused
    assert rows["campaign.lattice_n"][3] == "≥ 5; ≤ 400"
    parse_run_config({"campaign": {"lattice_n": 400}})
    try:
        parse_run_config({"campaign": {"lattice_n": 401}})
        raise AssertionError("lattice_n 401 was accepted")
    except ValueError as exc:
        assert "campaign.lattice_n" in str(exc)
    # a custom validator's list (policy names) is that validator's own message
    from core.policies.registry import policy_names

    assert all(name in rows["campaign.policy"][3] for name in policy_names())


def test_the_doc_example_is_a_valid_run_file() -> None:
    text = configdoc.DOC_PATH.read_text(encoding="utf-8")
    example = re.search(r"```toml\n(.*?)```", text, re.S)
    assert example is not None
    rc = parse_run_config(tomllib.loads(example.group(1)))
    assert rc.options.supervision == "supervised"


def test_check_mode_reports_a_stale_file(tmp_path, monkeypatch, capsys) -> None:  # type: ignore[no-untyped-def]
    stale = tmp_path / "config.md"
    stale.write_text("old\n", encoding="utf-8")
    monkeypatch.setattr(configdoc, "DOC_PATH", stale)
    assert configdoc.main(["--check"]) == 1
    assert "stale" in capsys.readouterr().err
    assert configdoc.main([]) == 0 and configdoc.main(["--check"]) == 0


def test_every_sample_field_is_documented_from_its_validator() -> None:
    rows = configdoc.sample_rows()
    names = [r[0] for r in rows]
    assert [r[0] for r in rows if not r[2]] == []
    assert set(configdoc.SAMPLE_MEANINGS) <= set(names), set(configdoc.SAMPLE_MEANINGS) - set(names)
    for must in ("name", "corners.tl", "safety.r_excl_um", "safety.stage_rect_um", "exclusions[].circle_um"):
        assert must in names
    defaults = {r[0]: r[1] for r in rows}
    from core.sample import Sample

    assert (
        defaults["safety.r_excl_um"] == f"`{Sample.r_excl_um!r}`"
    )  # the dataclass default the validator uses


def test_the_sample_template_in_the_doc_is_a_valid_sample_file() -> None:
    from core.sample import SAMPLE_TEMPLATE, parse_sample

    text = configdoc.DOC_PATH.read_text(encoding="utf-8")
    assert SAMPLE_TEMPLATE.rstrip() in text
    sample = parse_sample(tomllib.loads(SAMPLE_TEMPLATE), "template")
    assert len(sample.exclusions) == 2

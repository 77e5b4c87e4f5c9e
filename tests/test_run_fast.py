"""``aeni run --fast on|off`` and a run file's ``campaign.fast``: the run spec carries the choice (its policy's
``+fast``), one JSON across processes; a profile without a fast mode, or a policy that plans no fast arrays, is
one line and exit 2 with nothing left behind."""

from __future__ import annotations

from pathlib import Path

import pytest

from aeni_console.cli.main import main
from core.errors import InputError
from core.run.spec import RunSpec
from core.runconfig import load_run_config, policy_with_fast


def test_policy_with_fast_adds_or_drops_the_modifier_once() -> None:
    assert policy_with_fast("aeni", "on") == "aeni+fast"
    assert policy_with_fast("aeni+fast", "on") == "aeni+fast"
    assert policy_with_fast("aeni+fast+bends", "on") == "aeni+bends+fast"
    assert policy_with_fast("aeni+fast+bends", "off") == "aeni+bends"
    assert policy_with_fast("aeni+fast", None) == "aeni+fast"


def test_the_run_file_field_and_the_flag_are_carried_by_the_spec(tmp_path: Path) -> None:
    f = tmp_path / "run.toml"
    f.write_text('name = "f"\n[campaign]\nfast = "on"\n', encoding="utf-8")
    spec = load_run_config(f).spec()
    assert spec.campaign.policy == "aeni+fast" and spec.fast
    again = RunSpec.from_json(spec.to_json())  # what a detached engine and the journal read back
    assert again.fast and again.campaign.policy == "aeni+fast"
    off = load_run_config(f, {"campaign.fast": "off"}).spec()  # the flag overrides the file
    assert off.campaign.policy == "aeni" and not off.fast
    assert not load_run_config(None).spec().fast  # default: CSM only


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ('[campaign]\nfast = "yes"', "field campaign.fast = 'yes' is not allowed: must be 'on' or 'off'"),
        (
            '[campaign]\npolicy = "grid"\nfast = "on"',
            "field campaign.fast = 'on' is not allowed: policy 'grid' plans no fast arrays",
        ),
    ],
)
def test_a_bad_fast_field_is_one_line_naming_it(tmp_path: Path, text: str, says: str) -> None:
    f = tmp_path / "run.toml"
    f.write_text(text, encoding="utf-8")
    with pytest.raises(InputError) as err:
        load_run_config(f)
    assert says in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("how", ["--quiet", "--detach"])
def test_fast_on_with_a_profile_without_a_fast_mode_is_one_line_exit_2_and_no_journal(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, how: str
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "lab.toml").write_text(
        'extends = "kla-imicro"\nname = "lab"\n[fast]\navailable = false\n', encoding="utf-8"
    )
    (tmp_path / "run.toml").write_text(
        'name = "lab-run"\n[campaign]\nprofile = "lab.toml"\n[planner]\nbudget_s = 3000\n', encoding="utf-8"
    )
    assert main(["run", "run.toml", "--fast", "on", how]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "aeni: error: --fast: profile lab has no fast mode (no [fast] section)"
    assert not list(
        tmp_path.glob("runs/*")
    )  # no journal, and no engine log (a detached start is refused first)

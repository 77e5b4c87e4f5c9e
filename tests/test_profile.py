"""Instrument profiles: built-ins, TOML files, validation, and fitting a stage's move model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from core.errors import InputError
from core.profile import MoveModel, fit_move_model, load_profile, profile_from_dict, profile_to_dict


def test_builtins() -> None:
    p = load_profile("kla-imicro")
    assert (p.lift_s, p.engage_s, p.drift_settle_s, p.comeback_s) == (30, 65, 300, 35)
    assert p.reconfiguration_s == 390
    assert p.global_jump_s is None
    film = load_profile("kla-imicro-film")
    assert film.global_jump_s == 520 and film.lift_s == 30


def test_nanoblitz_profile_prices_fast_indents_without_hold() -> None:
    p = load_profile("kla-nanoblitz")
    assert p.allowed_holds_s == (0.0,) and p.default_hold_s == 0.0 and p.fast_hold_s == 0.0
    per_indent = p.indent_s(0.0) + p.move_s(5.0, 0.0)  # one indent and one 5 µm step inside a local grid
    assert 1.0 <= per_indent <= 2.0
    imicro = load_profile("kla-imicro")
    assert per_indent < 0.05 * (imicro.indent_s(imicro.default_hold_s) + imicro.move_s(5.0, 0.0))
    assert p.global_overhead_s == imicro.global_overhead_s  # fixed costs per program: the iMicro's (assumed)
    assert p.inview.method_for(0.0) == "NanoBlitz 3D.nmt"
    with pytest.raises(InputError, match="hold"):
        p.check_hold(5.0)
    assert profile_from_dict(profile_to_dict(p)) == p


def test_round_trip_dict() -> None:
    p = load_profile("kla-imicro-film")
    assert profile_from_dict(profile_to_dict(p)) == p


def test_custom_profile_file(tmp_path: Path) -> None:
    f = tmp_path / "lab.toml"
    f.write_text('name = "lab"\nextends = "kla-imicro"\n[steps]\ndrift_settle_s = 120\n', encoding="utf-8")
    p = load_profile(f)
    assert p.name == "lab" and p.drift_settle_s == 120 and p.engage_s == 65


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("[steps]\nlift_s = -3\n", "steps.lift_s"),
        ("[steps]\nlift_s = 'slow'\n", "steps.lift_s"),
        ("[steps]\nwarp_s = 3\n", "steps.warp_s"),
        ("[move]\nbreakpoint_um = 0\n", "move.breakpoint_um"),
        ("[steps]\nallowed_holds_s = [5]\n", "default_hold_s"),
        ("this is = = not toml", "not valid TOML"),
        ('extends = "nope"\n', "extends"),
    ],
)
def test_bad_profile_files_name_the_field(tmp_path: Path, text: str, needle: str) -> None:
    f = tmp_path / "bad.toml"
    f.write_text(text, encoding="utf-8")
    with pytest.raises(InputError) as exc:
        load_profile(f)
    assert needle in str(exc.value) and str(f) in str(exc.value)


def test_missing_profile() -> None:
    with pytest.raises(InputError, match="built-in profiles"):
        load_profile("/no/such/profile.toml")


def test_fit_move_model_recovers_known_parameters(tmp_path: Path) -> None:
    truth = MoveModel(short_a=4000.0, short_b=8e-7, short_c=3998.5, long_slope=2e-4, long_intercept=3.0)
    rng = np.random.default_rng(1)
    d = np.concatenate([rng.uniform(2, 499, 40), rng.uniform(500, 50_000, 40)])
    s = truth.axis_s_array(d) + rng.normal(0, 0.01, d.size)
    f = tmp_path / "moves.csv"
    f.write_text(
        "distance_um,seconds\n" + "\n".join(f"{a},{b}" for a, b in zip(d, s, strict=True)), encoding="utf-8"
    )
    fit = fit_move_model(f)
    assert fit.rmse_s < 0.02
    for dist in (5.0, 250.0, 800.0, 20_000.0):
        assert fit.model.axis_s(dist) == pytest.approx(truth.axis_s(dist), abs=0.03)


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("d,s\n1,2\n", "distance_um, seconds"),
        ("distance_um,seconds\n1,x\n2,3\n4,5\n6,7\n", "line 2"),
        ("distance_um,seconds\n1,2\n", "at least 4"),
        ("distance_um,seconds\n-1,2\n2,3\n4,5\n6,7\n", "≥ 0"),
    ],
)
def test_fit_move_model_bad_csv(tmp_path: Path, text: str, needle: str) -> None:
    f = tmp_path / "m.csv"
    f.write_text(text, encoding="utf-8")
    with pytest.raises(InputError, match=needle):
        fit_move_model(f)

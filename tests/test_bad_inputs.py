"""A new user's bad and odd inputs across the commands (issue 15's "Done when").

Every case must end in exit code 2 with one line on stderr that names the field or the file, no
traceback, and nothing written: the files of the case's folder and the run journal are byte-for-byte
what they were. The table is the point; add a row for each new way to get it wrong.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from aeni_console.cli.main import main
from core.campaign_config import CampaignConfig
from core.plan import PlannerSettings

DIR = object()  # a file spec that makes a folder


@dataclass(frozen=True)
class Case:
    id: str
    argv: tuple[str, ...]  # {t} is the case's folder, {run} a finished run's journal
    needles: tuple[str, ...]  # each must be in the one error line (the field or the file, and the problem)
    files: dict[str, object] = field(default_factory=dict)  # name: text, bytes or DIR


SAMPLE = 'name = "s"\n[corners]\ntl = { x_um = 0.0, y_um = 1000.0, z_um = 10.0 }\ntr = { x_um = 1000.0, y_um = 1000.0, z_um = 10.0 }\nbr = { x_um = 1000.0, y_um = 0.0, z_um = 10.0 }\nbl = { x_um = 0.0, y_um = 0.0, z_um = 10.0 }\n'
SAMPLE_FAR = 'name = "s"\n[corners]\ntl = { x_um = 30000.0, y_um = 21000.0, z_um = 10.0 }\ntr = { x_um = 31000.0, y_um = 21000.0, z_um = 10.0 }\nbr = { x_um = 31000.0, y_um = 20000.0, z_um = 10.0 }\nbl = { x_um = 30000.0, y_um = 20000.0, z_um = 10.0 }\n'
BOWTIE_ASYMMETRIC = "[[30100.0, 20100.0], [30400.0, 20400.0], [30400.0, 20100.0], [30100.0, 20300.0]]"
BOWTIE_SYMMETRIC = "[[30100.0, 20100.0], [30400.0, 20400.0], [30400.0, 20100.0], [30100.0, 20400.0]]"
LATTICE_CSV = "x_um,y_um,hardness_gpa\n0,0,3\n1000,0,4\n0,1000,5\n1000,1000,6\n500,500,4.5\n"

CASES: tuple[Case, ...] = (
    # ---- the run file ---------------------------------------------------------------------------
    Case("toml-syntax", ("run", "{t}/r.toml"), ("r.toml", "not valid TOML"), {"r.toml": "name = \n"}),
    Case("toml-binary", ("run", "{t}/r.toml"), ("r.toml",), {"r.toml": b"\xff\xfe\x00\x01"}),
    Case("toml-missing", ("run", "{t}/none.toml"), ("none.toml", "no such")),
    Case("toml-folder", ("run", "{t}/cfg"), ("cfg", "is a folder"), {"cfg": DIR}),
    Case("toml-typo", ("run", "{t}/r.toml"), ("plannr", "unknown field"), {"r.toml": "[plannr]\nbeta = 1\n"}),
    Case(
        "toml-unknown-key",
        ("run", "{t}/r.toml"),
        ("planner.betta", "unknown field"),
        {"r.toml": "[planner]\nbetta = 1\n"},
    ),
    Case("toml-beta-neg", ("run", "{t}/r.toml"), ("planner.beta",), {"r.toml": "[planner]\nbeta = -1\n"}),
    Case(
        "toml-beta-text", ("run", "{t}/r.toml"), ("planner.beta",), {"r.toml": '[planner]\nbeta = "high"\n'}
    ),
    Case(
        "toml-policy",
        ("run", "{t}/r.toml"),
        ("campaign.policy",),
        {"r.toml": '[campaign]\npolicy = "best"\n'},
    ),
    Case("toml-seed-neg", ("run", "{t}/r.toml"), ("campaign.seed",), {"r.toml": "[campaign]\nseed = -3\n"}),
    Case("toml-name-empty", ("run", "{t}/r.toml"), ("name",), {"r.toml": 'name = ""\n'}),
    Case(
        "toml-supervision",
        ("run", "{t}/r.toml"),
        ("run.supervision",),
        {"r.toml": '[run]\nsupervision = "sometimes"\n'},
    ),
    Case(
        "toml-lattice",
        ("run", "{t}/r.toml"),
        ("campaign.lattice_n",),
        {"r.toml": "[campaign]\nlattice_n = 2\n"},
    ),
    Case(
        "toml-budget-nan",
        ("run", "{t}/r.toml"),
        ("planner.budget_s",),
        {"r.toml": "[planner]\nbudget_s = nan\n"},
    ),
    Case(
        "toml-csv-no-truth",
        ("run", "{t}/r.toml"),
        ("campaign.truth_csv",),
        {"r.toml": '[campaign]\nscenario = "csv"\n'},
    ),
    Case("toml-section-not-table", ("run", "{t}/r.toml"), ("planner",), {"r.toml": 'planner = "fast"\n'}),
    Case("toml-speed-zero", ("run", "{t}/r.toml"), ("run.speed",), {"r.toml": "[run]\nspeed = 0\n"}),
    # ---- run flags ------------------------------------------------------------------------------
    Case("flag-seed-text", ("run", "--seed", "abc", "--journal", "{t}/j.sqlite"), ("campaign.seed",)),
    Case("flag-budget-neg", ("run", "--budget-s", "-5", "--journal", "{t}/j.sqlite"), ("planner.budget_s",)),
    Case(
        "flag-lattice-big",
        ("run", "--lattice-n", "5000", "--journal", "{t}/j.sqlite"),
        ("campaign.lattice_n",),
    ),
    Case("flag-speed-zero", ("run", "--speed", "0", "--journal", "{t}/j.sqlite"), ("run.speed",)),
    Case("flag-driver", ("run", "--driver", "kla9000", "--journal", "{t}/j.sqlite"), ("run.driver",)),
    Case("flag-policy", ("run", "--policy", "fastest", "--journal", "{t}/j.sqlite"), ("campaign.policy",)),
    Case(
        "flag-scenario", ("run", "--scenario", "ternery", "--journal", "{t}/j.sqlite"), ("campaign.scenario",)
    ),
    Case(
        "flag-supervision",
        ("run", "--supervision", "maybe", "--journal", "{t}/j.sqlite"),
        ("run.supervision",),
    ),
    Case(
        "journal-is-text",
        ("run", "--journal", "{t}/notes.txt"),
        ("notes.txt", "not a journal"),
        {"notes.txt": "x"},
    ),
    Case("journal-is-folder", ("run", "--journal", "{t}/out"), ("out", "is a folder"), {"out": DIR}),
    Case(
        "journal-under-file",
        ("run", "--journal", "{t}/f/j.sqlite"),
        ("f", "is a file"),
        {"f": "a file, not a folder"},
    ),
    Case("journal-exists", ("run", "--journal", "{run}"), ("aeni resume",)),
    # ---- sample files ---------------------------------------------------------------------------
    Case("sample-missing", ("run", "--sample", "{t}/s.toml", "--journal", "{t}/j.sqlite"), ("s.toml",)),
    Case(
        "sample-folder",
        ("run", "--sample", "{t}/s", "--journal", "{t}/j.sqlite"),
        ("s",),
        {"s": DIR},
    ),
    Case(
        "sample-in-mm",
        ("sample", "check", "{t}/s.toml"),
        ("s.toml", "mm"),
        {"s.toml": SAMPLE.replace("1000.0", "1.0")},
    ),
    Case(
        "sample-no-corner",
        ("sample", "check", "{t}/s.toml"),
        ("s.toml", "corners.bl"),
        {"s.toml": SAMPLE.rsplit("bl =", 1)[0]},
    ),
    Case(
        "sample-corner-in-mm",  # issue 23: one corner typed in mm passed with a warning
        ("sample", "check", "{t}/s.toml"),
        ("s.toml", "corners.bl", "mm"),
        {
            "s.toml": SAMPLE_FAR.replace(
                "bl = { x_um = 30000.0, y_um = 20000.0", "bl = { x_um = 30.0, y_um = 20.0"
            )
        },
    ),
    Case(
        "run-corner-in-mm",
        ("run", "--sample", "{t}/s.toml", "--journal", "{t}/j.sqlite"),
        ("s.toml", "corners.bl", "mm"),
        {
            "s.toml": SAMPLE_FAR.replace(
                "bl = { x_um = 30000.0, y_um = 20000.0", "bl = { x_um = 30.0, y_um = 20.0"
            )
        },
    ),
    Case(
        "sample-corner-in-nm",
        ("sample", "check", "{t}/s.toml"),
        ("s.toml", "corners.tr", "nm"),
        {
            "s.toml": SAMPLE_FAR.replace(
                "tr = { x_um = 31000.0, y_um = 21000.0", "tr = { x_um = 31000000.0, y_um = 21000000.0"
            )
        },
    ),
    Case(
        "sample-affine-misfit",  # 150 µm off a 1414 µm parallelogram: the fit misses by 2.7 %
        ("sample", "check", "{t}/s.toml"),
        ("s.toml", "affine fit", "2 %", "corners.bl"),
        {"s.toml": SAMPLE.replace("bl = { x_um = 0.0, y_um = 0.0", "bl = { x_um = 0.0, y_um = 150.0")},
    ),
    Case(
        "run-affine-misfit",
        ("run", "--sample", "{t}/s.toml", "--journal", "{t}/j.sqlite"),
        ("s.toml", "affine fit", "corners.bl"),
        {"s.toml": SAMPLE.replace("bl = { x_um = 0.0, y_um = 0.0", "bl = { x_um = 0.0, y_um = 150.0")},
    ),
    Case(
        "sample-typo",
        ("sample", "check", "{t}/s.toml"),
        ("s.toml", "safty"),
        {"s.toml": SAMPLE + "[safty]\nr_excl_um = 20\n"},
    ),
    # ---- cost -----------------------------------------------------------------------------------
    Case(
        "path-no-columns", ("cost", "path", "{t}/p.csv"), ("p.csv", "missing column"), {"p.csv": "x,y\n1,2\n"}
    ),
    Case(
        "path-text-number",
        ("cost", "path", "{t}/p.csv"),
        ("p.csv", "line 3"),
        {"p.csv": "x_um,y_um\n1,2\n3,four\n"},
    ),
    Case("path-empty-file", ("cost", "path", "{t}/p.csv"), ("p.csv",), {"p.csv": ""}),
    Case(
        "path-hold",
        ("cost", "path", "{t}/p.csv"),
        ("p.csv", "hold_s 30"),
        {"p.csv": "x_um,y_um,hold_s\n1,2,30\n"},
    ),
    Case("path-folder", ("cost", "path", "{t}/d"), ("d", "is a folder"), {"d": DIR}),
    Case("grid-blocks-zero", ("cost", "grid", "--blocks", "0"), ("--blocks",)),
    Case("grid-size-text", ("cost", "grid", "--size", "five"), ("--size",)),
    Case("grid-pitch-inf", ("cost", "grid", "--pitch-um", "inf"), ("--pitch-um",)),
    Case("grid-hold", ("cost", "grid", "--hold-s", "40"), ("--hold-s",)),
    Case("grid-profile-name", ("cost", "grid", "--profile", "imicro"), ("imicro",)),
    Case(
        "grid-profile-bad-toml",
        ("cost", "grid", "--profile", "{t}/p.toml"),
        ("p.toml",),
        {"p.toml": "[steps\nlift_s = 3\n"},
    ),
    Case("fit-move-missing", ("cost", "fit-move", "{t}/m.csv"), ("m.csv", "no such file")),
    Case(
        "fit-move-one-point",
        ("cost", "fit-move", "{t}/m.csv"),
        ("m.csv",),
        {"m.csv": "distance_um,seconds\n100,1.5\n"},
    ),
    Case(
        "fit-move-negative",
        ("cost", "fit-move", "{t}/m.csv"),
        ("m.csv",),
        {"m.csv": "distance_um,seconds\n" + "".join(f"{d},-1\n" for d in (1, 10, 100, 1000, 5000))},
    ),
    # ---- simulate -------------------------------------------------------------------------------
    Case("sim-truth-missing", ("simulate", "--truth", "{t}/t.csv"), ("t.csv",)),
    Case("sim-truth-folder", ("simulate", "--truth", "{t}/t"), ("t", "is a folder"), {"t": DIR}),
    Case(
        "sim-truth-columns",
        ("simulate", "--truth", "{t}/t.csv"),
        ("t.csv", "hardness_gpa"),
        {"t.csv": "x,y,h\n0,0,1\n"},
    ),
    Case(
        "sim-truth-text",
        ("simulate", "--truth", "{t}/t.csv"),
        ("t.csv",),
        {"t.csv": LATTICE_CSV.replace("4.5", "hard")},
    ),
    Case(
        "sim-truth-nan",
        ("simulate", "--truth", "{t}/t.csv"),
        ("t.csv",),
        {"t.csv": LATTICE_CSV.replace("4.5", "nan")},
    ),
    Case(
        "sim-truth-negative",
        ("simulate", "--truth", "{t}/t.csv"),
        ("t.csv",),
        {"t.csv": LATTICE_CSV.replace("4.5", "-4.5")},
    ),
    Case(
        "sim-truth-in-mpa",
        ("simulate", "--truth", "{t}/t.csv"),
        ("t.csv", "line 2", "hardness_gpa 3000 GPa is impossible", "looks like MPa"),
        {"t.csv": LATTICE_CSV.replace("0,0,3", "0,0,3000")},
    ),
    Case(
        "sim-truth-noise-in-mpa",
        ("simulate", "--truth", "{t}/t.csv"),
        ("t.csv", "line 2", "noise_sd_gpa 80 GPa", "MPa"),
        {
            "t.csv": "x_um,y_um,hardness_gpa,noise_sd_gpa\n0,0,3,80\n1000,0,4,0.1\n0,1000,5,0.1\n1000,1000,6,0.1\n"
        },
    ),
    Case(
        "sim-truth-in-nm",
        ("simulate", "--truth", "{t}/t.csv"),
        ("t.csv", "x_um 1e+06 µm", "looks like nm"),
        {"t.csv": LATTICE_CSV.replace("1000,", "1000000,")},
    ),
    Case(
        "path-far-away",
        ("cost", "path", "{t}/p.csv"),
        ("p.csv", "line 3: x_um 1e+12 µm"),
        {"p.csv": "x_um,y_um\n0,0\n1e12,0\n"},
    ),
    Case(
        "path-in-nm",
        ("cost", "path", "{t}/p.csv"),
        ("p.csv", "looks like nm"),
        {"p.csv": "x_um,y_um\n50000000,0\n"},
    ),
    Case("sim-scenario", ("simulate", "--scenario", "ternery"), ("ternery",)),
    Case("sim-seed-neg", ("simulate", "--seed", "-1"), ("--seed",)),
    Case("sim-budget-nan", ("simulate", "--budget-s", "nan"), ("--budget-s",)),
    Case("sim-policy", ("simulate", "--policy", "best"), ("--policy",)),
    Case("sim-failure-rate", ("simulate", "--failure-rate", "2"), ("failure_rate",)),
    Case(
        "sim-profile-missing", ("simulate", "--profile", "{t}/none.toml", "--budget-s", "100"), ("none.toml",)
    ),
    # ---- journals and runs ----------------------------------------------------------------------
    Case(
        "status-not-journal", ("status", "{t}/j.sqlite"), ("j.sqlite", "not an SQLite"), {"j.sqlite": "hello"}
    ),
    Case(
        "status-truncated",
        ("status", "{t}/j.sqlite"),
        ("j.sqlite",),
        {"j.sqlite": b"SQLite format 3\x00" + b"\x10\x00" + b"\x00" * 82},
    ),
    Case("status-missing", ("status", "{t}/nothing.sqlite"), ("nothing.sqlite",)),
    Case("status-folder", ("status", "{t}/d"), ("d", "is a folder"), {"d": DIR}),
    Case("replay-block", ("replay", "{run}", "--block", "999"), ("--block", "999")),
    Case("replay-block-text", ("replay", "{run}", "--block", "two"), ("--block",)),
    Case("export-format", ("export", "{run}", "--format", "xml", "--out", "{t}/o"), ("--format",)),
    Case(
        "export-out-file", ("export", "{run}", "--out", "{t}/o.csv"), ("o.csv", "is a file"), {"o.csv": "x"}
    ),
    Case("export-out-missing", ("export", "{run}"), ("--out",)),
    Case("resume-text", ("resume", "{t}/n.txt"), ("n.txt",), {"n.txt": "notes"}),
    Case("resume-speed", ("resume", "{run}", "--speed", "-2"), ("--speed",)),
    Case("resume-aborted", ("resume", "{aborted}"), ("aborted by", "--continue")),
    Case("resume-aborted-detach", ("resume", "{aborted}", "--detach"), ("aborted by", "--continue")),
    Case(
        "report-not-journal",
        ("report", "{t}/x.sqlite", "--out", "{t}/rep"),
        ("x.sqlite",),
        {"x.sqlite": "hi"},
    ),
    Case(
        "report-out-file", ("report", "{run}", "--out", "{t}/r.png"), ("r.png", "is a file"), {"r.png": "x"}
    ),
    Case("runs-file", ("runs", "{t}/x"), ("x", "is a file"), {"x": "x"}),
    Case("runs-missing", ("runs", "{t}/nope"), ("nope", "no such folder")),
    Case("send-no-fields", ("send", "{run}", "adjust"), ("adjust",)),
    Case("send-no-equals", ("send", "{run}", "adjust", "beta"), ("beta", "field=value")),
    Case("send-kind", ("send", "{run}", "explode"), ("explode",)),
    Case("send-finished", ("send", "{run}", "pause"), ("no engine is running",)),
    Case(
        "send-edge-penalty", ("send", "{run}", "adjust", "edge_penalty=0.99"), ("edge_penalty", "0 to 0.95")
    ),
    Case(
        "send-adjust-unknown", ("send", "{run}", "adjust", "speed=2"), ("speed", "not an adjustable setting")
    ),
    Case("send-adjust-hold", ("send", "{run}", "adjust", "fixed_hold_s=30"), ("fixed_hold_s", "0, 5, 80")),
    Case("send-beta-text", ("send", "{run}", "adjust", "beta=high"), ("beta",)),
    Case("send-veto-hold", ("send", "{run}", "veto", "hold_blocks=0"), ("hold_blocks", "whole number ≥ 1")),
    Case("send-pause-field", ("send", "{run}", "pause", "now=1"), ("now", "is not a field of pause")),
    Case("send-wait-zero", ("send", "{run}", "pause", "--wait-s", "0"), ("--wait-s",)),
    Case("console-missing", ("console", "{t}/gone.sqlite"), ("gone.sqlite",)),
    Case("demo-speed", ("demo", "--speed", "0"), ("--speed",)),
    Case("demo-seed", ("demo", "--seed", "x"), ("--seed",)),
    Case(
        "demo-journal-text",
        ("demo", "--journal", "{t}/n.txt"),
        ("n.txt", "not a journal"),
        {"n.txt": "notes"},
    ),
    Case("demo-policy", ("demo", "--policy", "fastest", "--journal", "{t}/d.sqlite"), ("policy", "fastest")),
    # ---- KLA exports ----------------------------------------------------------------------------
    Case("kla-not-excel", ("kla", "read", "{t}/e.xlsx"), ("e.xlsx",), {"e.xlsx": "test,h\n1,2\n"}),
    Case("kla-missing", ("kla", "read", "{t}/e.xls"), ("e.xls",)),
    Case("kla-empty", ("kla", "read", "{t}/e.xls"), ("e.xls",), {"e.xls": b""}),
    Case("kla-folder", ("kla", "read", "{t}/e.xlsx"), ("e.xlsx", "is a folder"), {"e.xlsx": DIR}),
    # ---- issue 38: inputs that passed silently, answers that were unclear -------------------------
    Case(
        "exclusion-circle-off-sample",  # a clamp typed wrong would be left unprotected
        ("sample", "check", "{t}/s.toml"),
        (
            "s.toml: field exclusions[0].circle_um = [5000.0, 5000.0, 100.0] lies entirely off the sample "
            "(29,055 µm from its edge), so it protects nothing: check its centre and radius (stage µm)",
        ),
        {"s.toml": SAMPLE_FAR + "[[exclusions]]\ncircle_um = [5000.0, 5000.0, 100.0]\n"},
    ),
    Case(
        "exclusion-bowtie-asymmetric",
        ("sample", "check", "{t}/s.toml"),
        (
            "s.toml: field exclusions[0].polygon_um crosses itself (its edge from vertex 0 to 1 meets the edge "
            "from vertex 2 to 3): list the vertices in order around the outline",
        ),
        {"s.toml": SAMPLE_FAR + f"[[exclusions]]\npolygon_um = {BOWTIE_ASYMMETRIC}\n"},
    ),
    Case(
        "exclusion-bowtie-symmetric",  # was "has no area (its vertices lie on one line)"
        ("sample", "check", "{t}/s.toml"),
        (
            "s.toml: field exclusions[0].polygon_um crosses itself (its edge from vertex 0 to 1 meets the edge "
            "from vertex 2 to 3): list the vertices in order around the outline",
        ),
        {"s.toml": SAMPLE_FAR + f"[[exclusions]]\npolygon_um = {BOWTIE_SYMMETRIC}\n"},
    ),
    Case(
        "exclusion-polygon-off-sample",
        ("sample", "check", "{t}/s.toml"),
        (
            "s.toml: field exclusions[0].polygon_um lies entirely off the sample, so it protects nothing: "
            "check its vertices (stage µm)",
        ),
        {"s.toml": SAMPLE_FAR + "[[exclusions]]\npolygon_um = [[0.0, 0.0], [500.0, 0.0], [0.0, 500.0]]\n"},
    ),
    Case(
        "avoid-centers-in-mm",
        ("run", "{t}/r.toml", "--journal", "{t}/j.sqlite"),
        (
            "r.toml: field planner.avoid_centers_um = [(30.5, 20.5), (30.2, 20.7)] lie far off sample 's' but "
            "on it when read as mm: these look like mm, but stage coordinates are µm (multiply by 1000)",
        ),
        {
            "s.toml": SAMPLE_FAR,
            "r.toml": '[sample]\nfile = "s.toml"\n[planner]\navoid_centers_um = [[30.5, 20.5], [30.2, 20.7]]\n',
        },
    ),
    Case(
        "kla-check-x-in-um",
        ("kla", "check", "--exchange", "{t}/x", "--x-mm", "30500", "--y-mm", "20.5"),
        (
            "--x-mm: 30500 mm is beyond the stage's 150 mm travel (profile kla-imicro, stage.travel_um); "
            "it looks like µm: 30.5 mm?",
        ),
        {"x": DIR},
    ),
    Case(
        "notify-url-typo",  # every alert of the night would have been lost
        ("run", "{t}/r.toml", "--journal", "{t}/j.sqlite"),
        (
            "r.toml: field notify.urls[0]: scheme jsn:// is not one apprise knows (did you mean json://?): no "
            "alert of the run could be sent",
        ),
        {"r.toml": '[notify]\nurls = ["jsn://127.0.0.1:8080/token"]\n'},
    ),
    Case(
        "earlier-csv-semicolons",
        ("sample", "check", "{t}/s.toml"),
        (
            "uses ';' as the separator (Excel in a decimal-comma locale); save it as comma-separated with '.' "
            "decimals",
            "earlier.indents_csv",
            "e.csv",
        ),
        {
            "s.toml": SAMPLE_FAR + '[earlier]\nindents_csv = "e.csv"\n',
            "e.csv": "x_um;y_um\r\n30100,5;20100,25\r\n",
        },
    ),
    Case(
        "send-finished-confirm",  # was "start it with `aeni resume`", which then had nothing to resume
        ("send", "{run}", "confirm", "ACDEF"),
        (
            "done.sqlite: no engine is running this journal: the run is finished (indent budget",
            "so it takes no more commands and there is nothing to resume",
        ),
    ),
    Case(
        "exchange-is-a-file",  # was "exchange folder does not exist"
        ("run", "--driver", "kla", "--exchange", "{t}/x", "--journal", "{t}/j.sqlite"),
        ("x: is a file, not a folder (the exchange folder is a folder shared with InView)",),
        {"x": "a file"},
    ),
    # ---- the command line itself ----------------------------------------------------------------
    Case("no-command", (), ("COMMAND",)),
    Case("unknown-command", ("indent",), ("indent",)),
)


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from aeni_console.cli.run import run_engine
    from core.runconfig import RunOptions

    path = tmp_path_factory.mktemp("bad-inputs-run") / "done.sqlite"
    run_engine(
        path,
        create=(CampaignConfig(name="done", settings=PlannerSettings(indent_budget=1)), RunOptions()),
        quiet=True,
    )
    return path


@pytest.fixture(scope="module")
def aborted_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A run the operator aborted after its first block (a real engine, a real abort command)."""
    import threading
    import time

    from aeni_console.cli.run import run_engine
    from core.journal import JournalReader, engine_running, send_command
    from core.runconfig import RunOptions
    from core.runview import Command, CommandKind

    path = tmp_path_factory.mktemp("bad-inputs-aborted") / "aborted.sqlite"
    cfg = CampaignConfig(name="aborted", settings=PlannerSettings(indent_budget=60))
    engine = threading.Thread(
        target=run_engine, args=(path,), kwargs={"create": (cfg, RunOptions(speed=2000.0)), "quiet": True}
    )
    engine.start()
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if path.exists() and engine_running(path):
            with JournalReader(path) as r:
                if r.blocks():
                    break
        time.sleep(0.05)
    send_command(path, Command(CommandKind.ABORT, author="tester"))
    engine.join(120)
    assert not engine.is_alive()
    return path


def test_resume_continue_resumes_an_aborted_run(aborted_run: Path, tmp_path: Path) -> None:
    import shutil

    from core.journal import JournalReader

    copy = tmp_path / "again.sqlite"
    shutil.copy(aborted_run, copy)
    with JournalReader(copy) as r:
        before = len(r.results())
    assert main(["resume", str(copy), "--continue", "--quiet", "--speed", "1e9"]) == 0
    with JournalReader(copy) as r:
        assert r.q.engine_row()["completed"]
        assert before < len(r.results()) <= 60  # it went on measuring, to the indent budget


def _tree(root: Path) -> dict[str, str]:
    out = {}
    for p in sorted(root.rglob("*")):
        out[str(p.relative_to(root))] = "DIR" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
    return out


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_input(
    case: Case,
    tmp_path: Path,
    finished_run: Path,
    capsys: pytest.CaptureFixture[str],
    request: pytest.FixtureRequest,
) -> None:
    for name, content in case.files.items():
        target = tmp_path / name
        if content is DIR:
            target.mkdir()
        elif isinstance(content, bytes):
            target.write_bytes(content)
        else:
            assert isinstance(content, str)
            target.write_text(content, encoding="utf-8")
    argv = [a.replace("{t}", str(tmp_path)).replace("{run}", str(finished_run)) for a in case.argv]
    if any("{aborted}" in a for a in argv):
        aborted = request.getfixturevalue("aborted_run")
        argv = [a.replace("{aborted}", str(aborted)) for a in argv]
    before, run_before = _tree(tmp_path), _tree(finished_run.parent)
    try:
        code = main(argv)
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    assert code == 2, f"exit {code}; stderr: {err!r}"
    assert out == "", f"stdout: {out!r}"
    assert "Traceback" not in err
    assert err.count("\n") == 1 and err.startswith("aeni: "), err
    for needle in case.needles:
        assert needle in err, f"{needle!r} not in {err!r}"
    assert _tree(tmp_path) == before, "something was written"
    assert _tree(finished_run.parent) == run_before, "the run's journal changed"


# ---- issue 38: files that are right, saved by Windows tools; checks that belong at start -------------------


def test_an_excel_csv_utf8_with_bom_and_crlf_is_accepted(tmp_path: Path) -> None:
    """Excel's "CSV UTF-8" starts with a byte-order mark and ends lines with CRLF: both are read."""
    from core.sample import load_sample

    (tmp_path / "e.csv").write_bytes(b"\xef\xbb\xbfx_um,y_um\r\n30100.5,20100.25\r\n30200,20300\r\n")
    (tmp_path / "s.toml").write_text(SAMPLE_FAR + '[earlier]\nindents_csv = "e.csv"\n', encoding="utf-8")
    assert load_sample(tmp_path / "s.toml").earlier_indents_um == ((30100.5, 20100.25), (30200.0, 20300.0))


def test_a_run_file_and_a_sample_file_with_a_bom_are_accepted(tmp_path: Path) -> None:
    from core.runconfig import load_run_config

    bom = b"\xef\xbb\xbf"
    (tmp_path / "s.toml").write_bytes(bom + SAMPLE_FAR.replace("\n", "\r\n").encode())
    (tmp_path / "r.toml").write_bytes(bom + b'name = "bom"\r\n[sample]\r\nfile = "s.toml"\r\n')
    rc = load_run_config(tmp_path / "r.toml")
    assert rc.campaign.name == "bom" and rc.campaign.sample is not None
    assert rc.campaign.sample.calibration.bounds_um == (30000.0, 31000.0, 20000.0, 21000.0)


def _refused(argv: list[str], capsys: pytest.CaptureFixture[str], root: Path) -> str:
    before = _tree(root)
    try:
        code = main(argv)
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    assert code == 2 and out == "" and "Traceback" not in err, (code, out, err)
    assert err.count("\n") == 1 and err.startswith("aeni: error: "), err
    assert _tree(root) == before, "something was written"
    return err.removeprefix("aeni: error: ").rstrip("\n")


def test_a_journal_of_a_newer_schema_is_called_newer(
    finished_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import shutil
    import sqlite3

    from core.journal.schema import SCHEMA_VERSION

    path = tmp_path / "newer.sqlite"
    shutil.copy(finished_run, path)
    with sqlite3.connect(path) as conn:
        conn.execute("UPDATE schema_version SET version = ?", (SCHEMA_VERSION + 1,))
    conn.close()
    err = _refused(["status", str(path)], capsys, tmp_path)
    assert err == (
        f"{path}: journal schema version {SCHEMA_VERSION + 1} is not supported: it was written by a newer release "
        f"(schema {SCHEMA_VERSION + 1} > {SCHEMA_VERSION}, the newest this program reads); open it with that release "
        "or a later one"
    )


@pytest.fixture
def read_only_share(tmp_path: Path) -> Iterator[Path]:
    """A share the instrument PC exports read-only, its outbox and inbox already there (the run used to wait
    silently on it): a read-only bind mount, since root writes through any chmod."""
    import subprocess

    share = tmp_path / "share"
    (share / "outbox").mkdir(parents=True)
    (share / "inbox").mkdir()

    def mount(*argv: str) -> subprocess.CompletedProcess[bytes]:
        return subprocess.run(["mount", *argv], capture_output=True, check=False)

    bound = mount("--bind", str(share), str(share))
    if bound.returncode != 0:
        pytest.skip(f"cannot bind-mount here ({bound.stderr.decode().strip() or 'no mount'})")
    try:
        if mount("-o", "remount,bind,ro", str(share)).returncode != 0:
            pytest.skip("cannot remount a bind mount read-only here")
        yield share
    finally:
        subprocess.run(["umount", str(share)], check=False)


def test_a_read_only_exchange_share_is_refused_at_start(
    read_only_share: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    journal = tmp_path / "j.sqlite"
    argv = ["run", "--driver", "kla", "--exchange", str(read_only_share), "--journal", str(journal)]
    err = _refused(argv, capsys, tmp_path)
    assert err == (
        f"{read_only_share}: exchange folder is not writable (Read-only file system): the run could not publish "
        "a block; mount the share read-write"
    )

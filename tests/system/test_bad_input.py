"""Bad input everywhere: one line on stderr, exit code 2, every file byte-identical.

Each case runs the CLI's ``main`` in a copy of one project folder (a study, a
sample set, an SQLite storage with finished verify trials, a journal with a
queued plan, a result cache), after writing the malformed file it needs; the
SHA-256 of every file in the folder, the storages included, is compared before
and after.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest

from surrogate._cli import main
from surrogate.identify._doe import make_design
from surrogate.identify._verify import enqueue, open_verify_study
from surrogate.identify._worker import work
from surrogate.study._spec import load_study
from tests.lab_files import BAD_LAB_FILES
from tests.workers.fixed_cost import FixedCostSolve

REPO = Path(__file__).resolve().parents[2]
STUDY = (REPO / "studies" / "paper_coating.toml").read_text()
MAGIC = STUDY + '\n[model]\neffects = ["magic"]\n'
HARDENING = '\n[model]\neffects = ["hardening"]\n'
SIM = ["simulate", "--ecoat", "1", "--scoat", "0.2", "--tcoat", "0.012"]
MEASURED = (REPO / "studies" / "webbing_tests.toml").read_text()
MEASURED = MEASURED.replace('"../data/measurements/', '"')  # the data beside it


def _study(old: str, new: str) -> str:
    assert old in STUDY, old
    return STUDY.replace(old, new, 1)


# (id, {file: text}, argv); "{d}" in argv is the case's folder
CASES = [
    ("study-not-toml", {"bad.toml": "[study\nname = 1"}, ["run", "bad.toml"]),
    ("study-unknown-section", {"bad.toml": STUDY + "\n[solvers]\nx = 1\n"}, ["run", "bad.toml"]),
    (
        "study-bad-name",
        {"bad.toml": _study('name = "paper-coating"', 'name = "bad name!"')},
        ["run", "bad.toml"],
    ),
    ("study-negative-seed", {"bad.toml": _study("seed = 0", "seed = -1")}, ["run", "bad.toml"]),
    (
        "study-low-above-high",
        {"bad.toml": _study("low = 0.5,  high = 4.0", "low = 5.0,  high = 4.0")},
        ["run", "bad.toml"],
    ),
    (
        "study-missing-parameter",
        {"bad.toml": _study("tcoat_mm  = { low = 0.01, high = 0.1, log = true }", "")},
        ["run", "bad.toml"],
    ),
    (
        "study-wrong-unit",
        {"bad.toml": _study("low = 0.5,  high = 4.0,", 'low = 0.5,  high = 4.0, unit = "MPa",')},
        ["run", "bad.toml"],
    ),
    (
        "study-budget-below-design",
        {"bad.toml": _study("max_solver_calls = 30", "max_solver_calls = 2")},
        ["run", "bad.toml"],
    ),
    (
        "study-unknown-solver",
        {"bad.toml": _study('kind = "builtin"', 'kind = "abaqus-not-here"')},
        ["run", "bad.toml"],
    ),
    (
        "study-tolerance-not-relative",
        {"bad.toml": _study("tolerance = 0.01", "tolerance = 2.0")},
        ["run", "bad.toml"],
    ),
    ("study-target-nan", {"bad.toml": _study("f60_n = 9.958", "f60_n = nan")}, ["run", "bad.toml"]),
    (
        "study-theta-above-range",
        {"bad.toml": _study("theta_sat_deg_min = 80.0", "theta_sat_deg_min = 95.0")},
        ["run", "bad.toml"],
    ),
    ("study-missing-file", {}, ["run", "no-such-study.toml"]),
    ("study-not-utf8", {"bad.toml": b"\xff\xfe[study]\n"}, ["run", "bad.toml"]),
    (
        "measurements-escape-project",
        {"bad.toml": STUDY + '\n[measurements]\nfile = "../../../etc/passwd"\n'},
        ["run", "bad.toml"],
    ),
    (
        "measurements-file-not-a-path",
        {"bad.toml": STUDY + "\n[measurements]\nfile = 3\n"},
        ["run", "bad.toml"],
    ),
    ("samples-missing-file", {}, ["fit", "nothing.csv"]),
    (
        "samples-nan",
        {
            "bad.csv": "run_id,ecoat_gpa,scoat_gpa,tcoat_mm,f60_n,theta_sat_deg,status\n"
            + "".join(f"{i},1,0.2,{'nan' if i == 2 else 0.01},9,80,ok\n" for i in range(1, 6))
        },
        ["fit", "bad.csv"],
    ),
    ("samples-no-columns", {"bad.csv": "a,b\n1,2\n"}, ["fit", "bad.csv"]),
    ("samples-binary", {"bad.csv": b"\x00\x01\x02\xff" * 64}, ["fit", "bad.csv"]),
    ("model-not-json", {"model.json": "{not json"}, ["predict", "model.json", "samples.csv"]),
    ("cli-negative-ecoat", {}, ["simulate", "--ecoat", "-1", "--scoat", "0.2", "--tcoat", "0.01"]),
    ("cli-nan-tcoat", {}, ["simulate", "--ecoat", "1", "--scoat", "0.2", "--tcoat", "nan"]),
    ("cli-unknown-option", {}, [*SIM, "--colour", "red"]),
    ("cli-budget-below-design", {}, ["run", "paper_coating.toml", "--budget", "2"]),
    ("cli-target-not-number", {}, ["run", "paper_coating.toml", "--target", "f60_n=abc"]),
    ("cli-negative-seed", {}, ["run", "paper_coating.toml", "--seed", "-3"]),
    ("cli-doe-zero-points", {}, ["doe", "--design", "lhs", "--n", "0", "--out", "x.csv"]),
    ("cli-doe-negative-seed", {}, ["doe", "--n", "2", "--seed", "-1", "--out", "x.csv"]),
    ("cli-fit-negative-seed", {}, ["fit", "samples.csv", "--seed", "-1", "--out", "m.json"]),
    ("cli-out-is-a-folder", {}, [*SIM, "--out", "{d}"]),
    ("cli-out-folder-missing", {}, ["fit", "samples.csv", "--out", "{d}/no/m.json"]),
    ("cli-predict-out-is-a-folder", {}, ["predict", "m.json", "samples.csv", "--out", "{d}"]),
    ("cli-privileged-port", {}, ["dashboard", "paper_coating.toml", "--port", "80"]),
    ("plugin-missing", {}, [*SIM, "--plugin", "no_such_plugin_module_xyz"]),
    ("plugin-not-a-module-name", {}, [*SIM, "--plugin", "../evil.py"]),
    ("effect-unknown", {}, [*SIM, "--effect", "no_such_effect"]),
    ("effect-value-not-number", {}, [*SIM, "--effect", "hardening:ratio=abc"]),
    (
        "storage-sqlite-many-workers",
        {},
        [
            "worker",
            "paper_coating.toml",
            "--storage",
            "sqlite:///{d}/paper-coating.db",
            "--jobs",
            "2",
        ],
    ),
    (
        "storage-sqlite-run-jobs",
        {},
        ["run", "paper_coating.toml", "--storage", "sqlite:///{d}/paper-coating.db", "--jobs", "3"],
    ),
    # an in-memory SQLite database: no other process sees it, so no worker ever could
    ("storage-memory-worker", {}, ["worker", "paper_coating.toml", "--storage", "sqlite://"]),
    (
        "storage-memory-plan-for-workers",
        {},
        ["run", "paper_coating.toml", "--storage", "sqlite:///:memory:", "--jobs", "0"],
    ),
    # … nor would a command that reads what another one stored
    ("storage-memory-dashboard", {}, ["dashboard", "paper_coating.toml", "--storage", "sqlite://"]),
    ("storage-memory-report", {}, ["report", "paper_coating.toml", "--storage", "sqlite://"]),
    ("storage-memory-export", {}, ["export", "paper_coating.toml", "--storage", "sqlite://"]),
    (
        "storage-memory-diagnose",
        {},
        ["diagnose", "webbing.toml", "--storage", "sqlite:///file::memory:?uri=true"],
    ),
    # compare reads a stored calibration unless --params gives the point
    ("storage-memory-compare", {}, ["compare", "webbing.toml", "--storage", "sqlite://"]),
    ("storage-unknown-scheme", {}, ["worker", "paper_coating.toml", "--storage", "bogus://x"]),
    ("storage-not-a-url", {}, ["worker", "paper_coating.toml", "--storage", "study.db"]),
    (
        "storage-journal-missing",
        {},
        ["worker", "paper_coating.toml", "--storage", "journal:///{d}/missing.log"],
    ),
    (
        "storage-postgres-unreachable",
        {},
        ["worker", "paper_coating.toml", "--storage", "postgresql://nobody@127.0.0.1:1/none"],
    ),
    (
        "storage-heartbeat-zero",
        {},
        ["worker", "paper_coating.toml", "--storage", "{d}/study.log", "--heartbeat", "0"],
    ),
    (
        "storage-patience-negative",
        {},
        ["worker", "paper_coating.toml", "--storage", "{d}/study.log", "--storage-patience", "-1"],
    ),
    (
        "run-storage-patience-negative",
        {},
        ["run", "paper_coating.toml", "--jobs", "0", "--storage-patience", "-1"],
    ),
    (
        "storage-study-not-planned",
        {"other.toml": _study('name = "paper-coating"', 'name = "other"')},
        ["worker", "other.toml", "--storage", "{d}/study.log"],
    ),
    (
        "storage-study-file-differs-from-plan",
        {"changed.toml": _study("friction = 0.1", "friction = 0.3")},
        ["worker", "changed.toml", "--storage", "sqlite:///{d}/paper-coating.db"],
    ),
    # [model] effects: an unknown name is refused by every command that reads the study;
    # the main job (run, worker, doe --run) refuses effects it cannot use
    *[
        (f"effect-unknown-{argv[0]}", {"magic.toml": MAGIC}, argv)
        for argv in (
            ["run", "magic.toml"],
            ["worker", "magic.toml", "--storage", "{d}/study.log"],
            ["export", "magic.toml"],
            ["dashboard", "magic.toml"],
            ["doe", "--study", "magic.toml", "--out", "x.csv"],
            ["calibrate", "magic.toml"],
            ["compare", "magic.toml"],
            ["diagnose", "magic.toml"],
        )
    ],
    # calibrate, compare and diagnose: refused before the work (a calibration used to run
    # its 12 runs, then say the storage's scheme was unknown or that 12 of 10 were used)
    ("calibrate-budget-below-design", {}, ["calibrate", "webbing.toml", "--budget", "10"]),
    (
        "calibrate-study-budget-below-design",
        {
            "small.toml": MEASURED.replace(
                "calibration_solver_calls = 200", "calibration_solver_calls = 11"
            )
        },
        ["calibrate", "small.toml"],
    ),
    ("calibrate-storage-unknown-scheme", {}, ["calibrate", "webbing.toml", "--storage", "foo://x"]),
    (
        "calibrate-storage-folder-missing",
        {},
        ["calibrate", "webbing.toml", "--storage", "sqlite:///{d}/no/x.db"],
    ),
    ("diagnose-storage-unknown-scheme", {}, ["diagnose", "webbing.toml", "--storage", "foo://x"]),
    ("compare-storage-unknown-scheme", {}, ["compare", "webbing.toml", "--storage", "foo://x"]),
    ("compare-nothing-calibrated", {}, ["compare", "webbing.toml"]),  # no empty storage left
    ("study-empty", {"empty.toml": ""}, ["run", "empty.toml"]),
    ("study-is-a-folder", {}, ["run", "{d}"]),
    ("samples-is-a-folder", {}, ["fit", "{d}"]),
    ("effect-known-run", {"hard.toml": STUDY + HARDENING}, ["run", "hard.toml"]),
    (
        "effect-known-doe-run",
        {"hard.toml": STUDY + HARDENING},
        ["doe", "--study", "hard.toml", "--run", "--n", "2", "--out", "x.csv"],
    ),
    # measurement files as labs export them, that cannot be read (tests/lab_files.py)
    *[(f"lab-{name}", files, ["calibrate", "lab.toml"]) for name, files, _ in BAD_LAB_FILES],
]

# what the one line must say, where a case's message was once a bare OS error or a
# finding made only after the work
SAYS = {
    "study-empty": "no [study] name; a study file starts with [study]",
    "study-is-a-folder": "is a folder; name a file in it",
    "samples-is-a-folder": "is a folder; name a file in it",
    "calibrate-budget-below-design": "--budget 10 is too small for this calibration: it "
    "needs at least 12 solver runs (an initial design of 8 and one verification: a run at "
    "each of the 4 condition groups)",
    "calibrate-study-budget-below-design": "[budget] calibration_solver_calls 11 is too small",
    "storage-patience-negative": "--storage-patience must be ≥ 0 s, got -1.0",
    "run-storage-patience-negative": "--storage-patience must be ≥ 0 s, got -1.0",
    "storage-memory-worker": "starts empty in every process, so a worker would find nothing",
    "storage-memory-dashboard": "so the dashboard would find nothing in it",
    "storage-memory-report": "so the report would find nothing in it",
    "storage-memory-export": "so export would find nothing in it",
    "storage-memory-diagnose": "so the diagnosis (it reads back its model ladder) would find",
    "storage-memory-compare": "so `compare` without --params would find nothing in it",
    "storage-memory-plan-for-workers": "so the workers --jobs 0 plans for would never see it",
    "calibrate-storage-unknown-scheme": "unknown scheme 'foo'",
    "calibrate-storage-folder-missing": "does not exist; create it first",
    "compare-storage-unknown-scheme": "unknown scheme 'foo'",
    "compare-nothing-calibrated": "run `surrogate calibrate` first or give --params",
    **{f"lab-{name}": says for name, _, says in BAD_LAB_FILES},
}


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    """A project folder with data, two storages and a result cache."""
    folder = tmp_path_factory.mktemp("project")
    (folder / "paper_coating.toml").write_text(STUDY)
    (folder / "webbing.toml").write_text(MEASURED)
    shutil.copy(REPO / "data" / "measurements" / "webbing_tests.csv", folder)
    for name in ("paper_stage1_samples.csv", "paper_stage1_samples_curves.csv"):
        shutil.copy(REPO / "data" / name, folder / name.replace("paper_stage1_", ""))
    spec = load_study(folder / "paper_coating.toml")
    points = make_design("lhs", spec.space, n=4, seed=0).to_dict("records")
    for storage, finished in ((spec.default_storage(), True), (f"{folder}/study.log", False)):
        enqueue(open_verify_study(spec, storage, heartbeat_s=None), spec, points, phase="p")
        if finished:
            solve = FixedCostSolve(folder / "solver.log", 0.0)
            work(spec, storage=storage, idle_timeout_s=0.0, solve=solve, progress=False)
    return folder


def _hashes(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.mark.parametrize(("files", "argv"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_is_one_line_exit_2_and_nothing_changes(
    files, argv, project, tmp_path, monkeypatch, capsys, request
):
    folder = tmp_path / "project"
    shutil.copytree(project, folder)
    for name, text in files.items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(text if isinstance(text, bytes) else text.encode())
    monkeypatch.chdir(folder)
    before = _hashes(folder)
    assert (folder / "paper-coating.db").exists() and (folder / ".solver-cache").is_dir()
    with pytest.raises(SystemExit) as stop:
        main([arg.replace("{d}", str(folder)) for arg in argv])
    err = capsys.readouterr().err
    assert stop.value.code == 2, err
    assert len(err.strip().splitlines()) == 1, err
    assert err.startswith("surrogate: error:") or err.startswith("surrogate "), err
    assert SAYS.get(request.node.callspec.id, "") in err
    assert _hashes(folder) == before


def test_there_are_at_least_25_cases():
    assert len(CASES) >= 25
    assert len({c[0] for c in CASES}) == len(CASES)
    assert set(SAYS) <= {c[0] for c in CASES}

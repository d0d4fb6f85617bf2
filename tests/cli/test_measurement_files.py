"""Measurement files that cannot be read, through the commands that read them: exit code
2, one line on stderr naming the file and the fix, and nothing written next to the study
(no storage, no result cache)."""

import numpy as np
import pytest

from tests.lab_files import BAD_LAB_FILES, STUDY


@pytest.mark.parametrize("command", ["calibrate", "compare", "diagnose"])
@pytest.mark.parametrize(
    ("files", "says"), [c[1:] for c in BAD_LAB_FILES], ids=[c[0] for c in BAD_LAB_FILES]
)
def test_a_bad_lab_file_is_one_line_exit_2_and_nothing_written(
    files, says, command, tmp_path, in_process
):
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text, encoding="utf-8")
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    code, _, err = in_process(command, "lab.toml", cwd=tmp_path)
    assert code == 2, err
    assert len(err.strip().splitlines()) == 1 and err.startswith("surrogate: error: "), err
    assert says in err, err
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before
    assert not list(tmp_path.glob("*.db")) and not (tmp_path / ".solver-cache").exists()


def test_odd_but_usable_data_is_one_warning_line(tmp_path, in_process):
    """Angles that end at 1.57 "degrees" (radians, likely): a warning, then the command goes
    on (here to its budget's refusal, before any run)."""
    rows = [
        f"T{t},{np.radians(a):.6f},{0.1 * a + 0.01 * t:.4f}" for t in (1, 2) for a in (0, 45, 90)
    ]
    (tmp_path / "t.csv").write_text("test_id,angle_deg,force_n\n" + "\n".join(rows) + "\n")
    (tmp_path / "lab.toml").write_text(STUDY.format(keys='file = "t.csv"'))
    code, _, err = in_process("calibrate", "lab.toml", "--budget", "1", cwd=tmp_path)
    warning, error = err.strip().splitlines()
    assert warning.startswith("surrogate: warning: ") and "the angles end at 1.5708°" in warning
    assert 'set [measurements] angle_unit = "rad"' in warning
    assert code == 2 and "--budget 1 is too small" in error

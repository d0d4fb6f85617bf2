"""Measurement files that cannot be read, through the command: exit code 2, one line on
stderr naming the file and the fix, and nothing written next to the study (no storage,
no result cache)."""

import pytest

from tests.lab_files import BAD_LAB_FILES


@pytest.mark.parametrize(
    ("files", "says"), [c[1:] for c in BAD_LAB_FILES], ids=[c[0] for c in BAD_LAB_FILES]
)
def test_a_bad_lab_file_is_one_line_exit_2_and_nothing_written(files, says, tmp_path, in_process):
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text, encoding="utf-8")
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    code, _, err = in_process("calibrate", "lab.toml", cwd=tmp_path)
    assert code == 2, err
    assert len(err.strip().splitlines()) == 1 and err.startswith("surrogate: error: "), err
    assert says in err, err
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before
    assert not list(tmp_path.glob("*.db")) and not (tmp_path / ".solver-cache").exists()

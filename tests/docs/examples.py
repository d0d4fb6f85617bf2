"""The examples of the manual and the README, run as tests.

The convention, for whoever writes a page of the manual or the README:

- A fenced block marked ```` ```console ```` is one command: its first line is
  ``$ command`` (continued on lines ending in ``\\``), the rest is the output shown.
  It is run with ``bash`` in a temporary copy of the repository's ``studies/``, ``data/``
  and ``examples/`` (one copy a page, the blocks in page order, so a page's later
  commands see what its earlier ones stored), with ``.venv/bin`` first on ``PATH``;
  stdout and stderr are read together.
- An HTML comment on the line before the block says what is checked::

      <!-- check: exit=2 rtol=0.05 keys: "target met" "F60 = 10.02 N" -->

  ``exit`` (default 0) is the expected exit code. With ``keys``, each quoted key line
  must appear in the shown output *and* in the real output, in that order; without, every
  shown output line must, in order, except lines that are ``…``. Lines are compared with
  whitespace collapsed and numbers equal within ``rtol`` (default 0.02), so a
  last-digit difference between machines is no failure but a changed result is.
  ``<!-- check: skip -->`` leaves a block out (say why next to it); ``needs=ccx`` skips it
  where the program is not installed, but not in CI (``CI=true``), where it must be.
- A ```` ```python ```` block runs (in the same temporary folder, in page order, each block
  in a fresh Python process: a block imports what it uses) and must not raise; a
  ```` ```pycon ```` block is a doctest (``>>>`` lines and their output; ELLIPSIS and
  NORMALIZE_WHITESPACE on).
- Any other block (``bash``, ``text``, ``toml``) is shown, not run: use them for
  commands that need what a test machine lacks (LS-DYNA, a PostgreSQL server, a browser).
- A page whose examples take long says ``<!-- check-page: slow -->``; its test is marked
  slow (CI runs it: CI runs the whole suite).
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
COPIED = ("studies", "data", "examples", "tests/solvers/fixtures")  # the last: stand-ins
_FENCE = re.compile(r"^```(\w*)[^\n]*\n(.*?)^```\s*$", re.DOTALL | re.MULTILINE)
_CHECK = re.compile(r"<!--\s*check:(.*?)-->\s*$")
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
ELLIPSIS_LINES = {"…", "...", "[…]"}


@dataclass
class Block:
    """One runnable fenced block of a page."""

    language: str
    text: str
    line: int  # where it starts in the page (1-based)
    exit: int = 0
    rtol: float = 0.02
    keys: list[str] | None = None
    skip: bool = False
    needs: list[str] = field(default_factory=list)  # programs it runs (e.g. ccx)

    @property
    def command(self) -> str:
        lines = self.text.splitlines()
        command = [lines[0].removeprefix("$ ")]
        for line in lines[1:]:
            if not command[-1].endswith("\\"):
                break
            command.append(line)
        return "\n".join(command)

    @property
    def shown(self) -> list[str]:
        """The output lines the page shows under the command."""
        return self.text.splitlines()[len(self.command.splitlines()) :]


@dataclass
class Page:
    path: Path
    blocks: list[Block] = field(default_factory=list)
    slow: bool = False


def parse_page(path: Path) -> Page:
    """The runnable blocks of a Markdown page, with their check options."""
    text = path.read_text(encoding="utf-8")
    page = Page(path, slow="<!-- check-page: slow -->" in text)
    for match in _FENCE.finditer(text):
        language, body = match.group(1), match.group(2)
        if language not in ("console", "python", "pycon"):
            continue
        before = text[: match.start()].rstrip("\n").rsplit("\n", 1)[-1]
        block = Block(language, body, text[: match.start()].count("\n") + 1)
        check = _CHECK.search(before)
        if check:
            _options(block, check.group(1))
        if language == "console" and not body.startswith("$ "):
            raise ValueError(f"{path}:{block.line}: a console block starts with '$ command'")
        page.blocks.append(block)
    return page


def _options(block: Block, text: str) -> None:
    head, _, keys = text.partition("keys:")
    for word in shlex.split(head):
        name, _, value = word.partition("=")
        if name == "skip":
            block.skip = True
        elif name == "exit":
            block.exit = int(value)
        elif name == "needs":
            block.needs = value.split(",")
        elif name == "rtol":
            block.rtol = float(value)
        else:
            raise ValueError(f"unknown check option {word!r} (exit=, rtol=, skip, keys:)")
    if keys.strip():
        block.keys = shlex.split(keys)


def workspace(root: Path) -> Path:
    """A temporary copy of what the examples read and write (nothing in the checkout)."""
    for name in COPIED:
        shutil.copytree(
            REPO / name,
            root / name,
            ignore=shutil.ignore_patterns(
                "*.db", ".solver-cache", "*-compare", "*-artifacts", "*-report.html", "__pycache__"
            ),
        )
    return root


def environment() -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["COLUMNS"] = "100"
    env.pop("PYTHONPATH", None)
    return env


def run_console(block: Block, cwd: Path) -> str:
    """Run the block's command; return its output, or raise AssertionError saying why."""
    done = subprocess.run(
        ["bash", "-c", block.command],
        cwd=cwd,
        env=environment(),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,  # one stream: progress lines stay where they were printed
        text=True,
        timeout=900,
    )
    output = done.stdout
    if done.returncode != block.exit:
        raise AssertionError(
            f"line {block.line}: `{block.command}` exited {done.returncode}, "
            f"expected {block.exit}:\n{output[-3000:]}"
        )
    return output


def compare(block: Block, output: str) -> None:
    """Each expected line (the keys, else every shown line) in the real output, in order."""
    shown = [line for line in block.shown if line.strip() not in ELLIPSIS_LINES]
    if block.keys is not None:
        missing = [key for key in block.keys if not _find_in_order(shown, [key], block.rtol)[0]]
        if missing:
            raise AssertionError(
                f"line {block.line}: key(s) {missing} are not in the output the page shows"
            )
        expected = block.keys
    else:
        expected = [line for line in shown if line.strip()]
    found, missing_line = _find_in_order(output.splitlines(), expected, block.rtol)
    if not found:
        raise AssertionError(
            f"line {block.line}: `{block.command}`: expected {missing_line!r} "
            f"(in this order, numbers within rtol={block.rtol}), got:\n{output[-4000:]}"
        )


def _find_in_order(lines: list[str], expected: list[str], rtol: float) -> tuple[bool, str]:
    """Whether each of ``expected`` is found after the one before (on a later line or
    further along the same one); else the first one not found."""
    line, column = 0, 0
    for want in expected:
        while line < len(lines):
            end = search(want, lines[line], rtol, column)
            if end >= 0:
                column = end
                break
            line, column = line + 1, 0
        else:
            return False, want
    return True, ""


def matches(want: str, line: str, rtol: float) -> bool:
    """Whether ``line`` contains ``want``, whitespace collapsed, numbers within ``rtol``."""
    return search(want, line, rtol, 0) >= 0


def search(want: str, line: str, rtol: float, start: int) -> int:
    """Where ``want`` ends in ``line`` (whitespace collapsed) from ``start`` on, or -1."""
    want, line = " ".join(want.split()), " ".join(line.split())
    numbers = _NUMBER.findall(want)
    literals = _NUMBER.split(want)
    pattern = "".join(
        re.escape(literal) + (f"({_NUMBER.pattern})" if index < len(numbers) else "")
        for index, literal in enumerate(literals)
    )
    for found in re.compile(pattern).finditer(line, start):
        pairs = zip(numbers, found.groups(), strict=True)
        if all(_close(float(a), float(b), rtol) for a, b in pairs):
            return found.end()
    return -1


def _close(want: float, got: float, rtol: float) -> bool:
    return abs(want - got) <= rtol * max(abs(want), abs(got)) or want == got


_RUNNER = """
import doctest, sys
language, path = sys.argv[1], sys.argv[2]
text = open(path, encoding="utf-8").read()
sys.path.insert(0, "examples")
if language == "python":
    exec(compile(text, "<block>", "exec"), {"__name__": "__docs__"})
else:
    test = doctest.DocTestParser().get_doctest(text, {"__name__": "__docs__"}, "block", None, 0)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    runner.run(test, out=sys.stdout.write)
    sys.exit(1 if runner.failures else 0)
"""


def run_python(block: Block, cwd: Path) -> None:
    """A python block (run, must not raise) or a pycon block (a doctest), in a process of
    its own — a block that registers an effect or a solver leaves the tests' process as it
    was — in the page's workspace."""
    source = cwd / f".block-{block.line}.txt"
    source.write_text(block.text, encoding="utf-8")
    done = subprocess.run(
        [sys.executable, "-c", _RUNNER, block.language, str(source)],
        cwd=cwd,
        env=environment(),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        timeout=900,
    )
    if done.returncode != 0:
        raise AssertionError(f"line {block.line} ({block.language}):\n{done.stdout[-4000:]}")


def _missing(programs: list[str]) -> bool:
    """Whether a program the block runs is not installed (never so in CI: it must be)."""
    absent = [p for p in programs if shutil.which(p) is None]
    if absent and os.environ.get("CI") == "true":
        raise AssertionError(f"{', '.join(absent)} not installed (scripts/system-packages.sh)")
    return bool(absent)


def check_page(path: Path, tmp: Path) -> int:
    """Run every example of ``path`` in a fresh workspace; return how many ran."""
    page = parse_page(path)
    cwd = workspace(tmp)
    ran = 0
    for block in page.blocks:
        if block.skip or _missing(block.needs):
            continue
        if block.language == "console":
            compare(block, run_console(block, cwd))
        else:
            run_python(block, cwd)
        ran += 1
    return ran

"""README.md and docs/*.md run as written (issue 19), the way cram or doctest keep docs honest.

One test per document: every line of every ```sh block and every ```python block is run, in
document order, in the document's own scratch directory (so ``echo s3cret > token.txt`` in one
block serves the later ones; the other documents start where the README's setup block leaves a
user: SETUP):

- a shell line runs with ``bash -c`` and ``PATH`` starting with this interpreter's directory,
  which is what ``. .venv/bin/activate`` gives a user (``python`` and the console scripts);
- the documented addresses are the ones in ADDRESSES, replaced by those of a cell served for
  the block (``cell serve --clock real``: robot and sensor share one scene, as ``sync delay``
  needs) when the block names one; the cell stands for the reader's robot and sensor and
  announces a short frame timeout (SERVED_FRAME_TIMEOUT), so a conformance run against it does
  not wait the spec's 5 s default in its frame-timeout case (the in-process reference of
  docs/CLI.md's ``conformance robot`` still does); a fresh cell per block, so a move in one
  block does not leave the arm somewhere the next block's example does not expect (``sync
  delay`` needs the sensor over the seam); the next block's cell starts while a block runs,
  and a used cell's shutdown is waited for at the end (:class:`Cells`);
- a ``serve`` line runs for ever, so it is started with its ports overridden to 0 (appended
  options: argparse keeps the last), must come up and is then stopped with SIGINT; it comes
  up while the block's later lines run and is checked when the block ends;
- a line whose comment says ``→ exit N`` must end with N, every other line with 0;
- SKIPPED lists the lines not run, each with the reason; FROM_CHECKOUT the checkout files copied
  into the scratch directory (the examples run from the clone's root).
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

# documented address -> which endpoint of the block's served cell stands in for it
ADDRESSES = {
    "127.0.0.1:4000": "robot",
    "127.0.0.1:2000": "sensor",
    "127.0.0.1:2001": "udp",
    "10.0.0.5:4000": "robot",
    "10.0.0.6:2000": "sensor",
    "10.0.0.6:2001": "udp",
}

SKIPPED = {
    # `make test` runs this very test; `make demo` is `python -m cell demo`, which runs below
    "make demo": "make: its command `python -m cell demo` is run from the README itself",
    "make test": "make: would run this test suite inside itself",
    # the test's PATH already starts with the interpreter's bin directory
    ". .venv/bin/activate": "the test runs with the .venv's bin directory first on PATH",
}

SERVE = re.compile(r"\b(?:robotsocket|sensorsocket|cell) serve\b")  # also rsf-cell, -m cell
PORTS_TO_ZERO = {
    "robotsocket": " --port 0 --udp-port 0",
    "sensorsocket": " --port 0 --udp-port 0",
    "cell": " --robot-port 0 --sensor-port 0 --udp-port 0",
}
EXPECTED_EXIT = re.compile(r"#.*→ exit (\d+)")
TIMEOUT_S = 180.0
SERVED_FRAME_TIMEOUT = "0.5"  # s, announced in Hello and checked by the harness all the same


@dataclass(frozen=True)
class Block:
    document: str
    line: int
    language: str
    text: str

    @property
    def id(self) -> str:
        return f"{self.document}:{self.line}"

    def commands(self) -> list[str]:
        """The block's shell commands: continuation lines joined, comment-only lines left out."""
        out: list[str] = []
        pending = ""
        for raw in self.text.splitlines():
            if pending:
                pending += " " + raw.strip()
            elif raw.strip() and not raw.lstrip().startswith("#"):
                pending = raw.strip()
            else:
                continue
            if pending.endswith("\\"):
                pending = pending[:-1].rstrip()
            else:
                out.append(pending)
                pending = ""
        return out


def blocks() -> list[Block]:
    found: list[Block] = []
    fence = re.compile(r"^```(\w*)\s*$")
    for path in DOCUMENTS:
        lines = path.read_text(encoding="utf-8").splitlines()
        i = 0
        while i < len(lines):
            m = fence.match(lines[i])
            if not m:
                i += 1
                continue
            end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith("```"))
            if m.group(1) in ("sh", "python"):
                text = "\n".join(lines[i + 1 : end])
                found.append(Block(path.relative_to(ROOT).as_posix(), i + 1, m.group(1), text))
            i = end + 1
    return found


BLOCKS = blocks()
EXAMPLES = [
    d for d in DOCUMENTS if any(b.document == d.relative_to(ROOT).as_posix() for b in BLOCKS)
]


# the scratch directory stands in for the clone: the checkout files the examples read
FROM_CHECKOUT = ["spec/capture.bin"]
# where a user who opens docs/*.md stands: the README's block that activates the venv has run
SETUP = next(b for b in BLOCKS if ". .venv/bin/activate" in b.commands())


def _scratch(path: Path) -> Path:
    for name in FROM_CHECKOUT:
        (path / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(ROOT / name, path / name)
    return path


def _env() -> dict[str, str]:
    bindir = str(Path(sys.executable).parent)
    env = dict(os.environ, PATH=bindir + os.pathsep + os.environ.get("PATH", ""))
    env.pop("PYTHONPATH", None)  # the installed package, as for a user
    return env


@dataclass
class Cell:
    robot: str
    sensor: str
    udp: str


def _names_an_address(block: Block) -> bool:
    return _substitute(block.text, Cell("robot:1", "sensor:2", "udp:3")) != block.text


def _start_cell(workdir: Path) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "cell", "serve", "--clock", "real", "--robot-port", "0",
         "--sensor-port", "0", "--udp-port", "0", "--frame-timeout", SERVED_FRAME_TIMEOUT],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=_env(), cwd=workdir,
    )  # fmt: skip


def _described(proc: subprocess.Popen[str]) -> Cell:
    assert proc.stdout is not None
    described: dict[str, str] = {}
    while "true_delta_t_ms" not in described:
        line = proc.stdout.readline()
        assert line, "cell serve ended before describing the cell"
        key, _, value = line.partition(":")
        described[key.strip()] = value.strip()
    return Cell(described["robot"], described["sensor"], described["udp"])


class Cells:
    """The served cells of one document: a fresh cell for each block that names an address.

    :meth:`prefetch` starts the next block's cell while the current block runs, and a used
    cell is stopped (SIGINT) when its block ends but waited for only in :meth:`close`: the
    blocks do not wait for a cell's start-up (about 1 s) or its shutdown. Each cell still
    serves one block only, so a move in one block does not leave the arm somewhere the next
    block's example does not expect.
    """

    def __init__(self, workdir: Path) -> None:
        self.workdir = workdir
        self.next: subprocess.Popen[str] | None = None
        self.stopping: list[subprocess.Popen[str]] = []

    def prefetch(self) -> None:
        if self.next is None:
            self.next = _start_cell(self.workdir)

    @contextmanager
    def take(self) -> Iterator[Cell]:
        self.prefetch()
        proc, self.next = self.next, None
        assert proc is not None
        try:
            yield _described(proc)
        finally:
            proc.send_signal(signal.SIGINT)
            self.stopping.append(proc)

    def close(self) -> None:
        if self.next is not None:
            self.next.send_signal(signal.SIGINT)
            self.stopping.append(self.next)
            self.next = None
        for proc in self.stopping:
            _wait_or_kill(proc)


def _interrupt(proc: subprocess.Popen[str]) -> None:
    proc.send_signal(signal.SIGINT)
    _wait_or_kill(proc)


def _wait_or_kill(proc: subprocess.Popen[str]) -> None:
    try:
        proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def _substitute(text: str, cell: Cell | None) -> str:
    if cell is None:
        return text
    for documented, role in ADDRESSES.items():
        served = getattr(cell, role)
        host, port = documented.split(":")
        served_host, served_port = served.split(":")
        text = text.replace(documented, served)
        text = text.replace(f'"{host}", {port}', f'"{served_host}", {served_port}')
    return text


def _serve(command: str, workdir: Path) -> subprocess.Popen[str]:
    """Start a serve line; :func:`_check_served` then says whether it came up."""
    tool = next(name for name in PORTS_TO_ZERO if re.search(rf"\b{name} serve\b", command))
    return subprocess.Popen(
        ["bash", "-c", "exec " + command.split("#")[0] + PORTS_TO_ZERO[tool]],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=_env(), cwd=workdir,
    )  # fmt: skip


def _check_served(command: str, proc: subprocess.Popen[str]) -> None:
    """A serve line must come up (it names its address) and stop on SIGINT."""
    seen: list[str] = []
    try:
        assert proc.stdout is not None
        while True:
            line = proc.stdout.readline()
            assert line, f"{command!r} ended before serving:\n{''.join(seen)}"
            seen.append(line)
            if re.search(r"listening on|serving tcp|true_delta_t_ms", line):
                break
    finally:
        _interrupt(proc)


def _interesting(output: str) -> str:
    """The output without the passing lines of a conformance run, at most 6000 characters."""
    kept = [line for line in output.splitlines() if not line.lstrip().startswith("pass ")]
    return "\n".join(kept)[-6000:]


def test_documents_have_examples() -> None:
    assert {b.document for b in BLOCKS} >= {"README.md"}
    assert sum(len(b.commands()) for b in BLOCKS if b.language == "sh") >= 30


@pytest.mark.parametrize("document", DOCUMENTS, ids=[d.name for d in DOCUMENTS])
def test_relative_links_resolve(document: Path) -> None:
    text = document.read_text(encoding="utf-8")
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    local = [t for t in targets if not re.match(r"\w+:", t)]
    missing = [t for t in local if not (document.parent / t).exists()]
    assert not missing, f"{document.name}: no such file: {missing}"


def test_commands_split_on_continuations_and_drop_comment_lines() -> None:
    block = Block("x", 1, "sh", "# a comment\npython -m x \\\n    --y 1   # why\n\nls")
    assert block.commands() == ["python -m x --y 1   # why", "ls"]


def _run(block: Block, cell: Cell | None, workdir: Path) -> None:
    if block.language == "python":
        proc = subprocess.run(
            [sys.executable, "-c", _substitute(block.text, cell)],
            capture_output=True, text=True, env=_env(), cwd=workdir, timeout=TIMEOUT_S,
        )  # fmt: skip
        assert proc.returncode == 0, f"{block.id}\n{proc.stdout}\n{proc.stderr}"
        return
    # a serve line's server comes up while the block's later lines run; checked at the end
    serving: list[tuple[str, subprocess.Popen[str]]] = []
    try:
        for command in block.commands():
            if command in SKIPPED or command.split("#")[0].strip() in SKIPPED:
                continue
            command = _substitute(command, cell)
            if SERVE.search(command):
                serving.append((command, _serve(command, workdir)))
                continue
            m = EXPECTED_EXIT.search(command)
            expected = int(m.group(1)) if m else 0
            proc = subprocess.run(
                ["bash", "-c", command],
                capture_output=True, text=True, env=_env(), cwd=workdir, timeout=TIMEOUT_S,
            )  # fmt: skip
            assert proc.returncode == expected, (
                f"{block.id}: {command}\nexit {proc.returncode}, documented {expected}\n"
                f"{_interesting(proc.stdout)}\n{proc.stderr[-3000:]}"
            )
    finally:
        _check_all_served(serving)


def _check_all_served(serving: list[tuple[str, subprocess.Popen[str]]]) -> None:
    """Every server checked and stopped, even when an earlier one failed its check."""
    if serving:
        command, server = serving[0]
        try:
            _check_served(command, server)
        finally:
            _check_all_served(serving[1:])


@pytest.mark.slow  # about 4 min in all: the documents' end-to-end runs
@pytest.mark.parametrize("document", EXAMPLES, ids=[d.name for d in EXAMPLES])
def test_examples_run_as_written(document: Path, tmp_path: Path, subtests: pytest.Subtests) -> None:
    name = document.relative_to(ROOT).as_posix()
    workdir = _scratch(tmp_path)
    if name != SETUP.document:
        _run(SETUP, None, workdir)
    mine = [b for b in BLOCKS if b.document == name]
    cells = Cells(workdir)
    try:
        for block, following in zip(mine, [*mine[1:], None], strict=True):
            # a subtest per block: a failing block is reported and the later ones still run
            with subtests.test(block.id):
                named = _names_an_address(block)
                # a fresh cell per block: the arm at its ready pose
                with cells.take() if named else nullcontext() as cell:
                    if following is not None and _names_an_address(following):
                        cells.prefetch()
                    _run(block, cell, workdir)
    finally:
        cells.close()

"""The user guide (docs/) runs: every shell command it shows, and the NovAtel commands it lists.

Each ```sh block of a guide page is preceded by a marker comment:

- ``<!-- test -->`` or ``<!-- test: OPTIONS -->``: run every line through the real ``rig`` CLI (a
  subprocess) in one working directory holding ``sim.toml`` (the shipped simulated car),
  ``car.toml`` (the car template) and ``sessions/day1`` (a simulated session). OPTIONS:
  ``session`` (this block records ``sessions/day1``; run once per module, first),
  ``exit N [N ...]`` (accepted exit statuses, default 0), ``output "TEXT"`` (a line the command
  prints, on stdout or stderr).
- ``<!-- not run: REASON -->``: needs hardware; the reason is required.

A ```text block after ``<!-- novatel-commands: CONFIG RECEIVER -->`` must be exactly the commands the
driver sends that receiver for that configuration, and the simulated receiver answers ``<OK`` to each.
"""

from __future__ import annotations

import fcntl
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import serial

from drivers.novatel import Framer
from drivers.novatel.framer import FrameKind
from rig.core.config import load_session
from rig.record.gnss import receiver_commands
from sim_devices.gnss import SimBase, SimRover, SimTimeBase
from sim_devices.vehicle import make_scenario, simulate
from vsccore.clock import ScaledClock

REPO = Path(__file__).resolve().parents[2]
DOCS = REPO / "docs"
GUIDE_PAGES = sorted(p for p in DOCS.rglob("*.md"))
COMMAND_TIMEOUT_S = 1500.0
"""A hang guard per command, not a speed requirement. The session block records the demo drive (164 s of
simulated time) at --speed 8 on a governed clock, which slows down on a busy host instead of degrading the
figures: 156 s with the rest of the suite on 4 workers on an idle 2-core machine, 353 s with 6 busy processes
besides (2026-12-05); once over 600 s, the old guard. The tests' own pytest timeout (3000 s) stays above it."""

_MARKER = re.compile(r"<!--\s*(?P<body>.*?)\s*-->\s*\n(?:\s*\n)*```(?P<lang>\w*)[^\n]*\n(?P<code>.*?)^```",
                     re.DOTALL | re.MULTILINE)
_FENCE = re.compile(r"^```(?P<lang>\w*)[^\n]*\n(?P<code>.*?)^```", re.DOTALL | re.MULTILINE)


@dataclass(frozen=True)
class Block:
    page: Path
    line: int
    marker: str
    lang: str
    code: str

    @property
    def where(self) -> str:
        return f"{self.page.relative_to(REPO)}:{self.line}"

    def commands(self) -> list[str]:
        return [ln.strip() for ln in self.code.splitlines() if ln.strip() and not ln.strip().startswith("#")]


@dataclass(frozen=True)
class RunSpec:
    session: bool
    exits: frozenset[int]
    output: str | None


def marked_blocks(page: Path) -> list[Block]:
    text = page.read_text(encoding="utf-8")
    return [Block(page, text.count("\n", 0, m.start("lang")) + 1, m.group("body"), m.group("lang"), m.group("code"))
            for m in _MARKER.finditer(text)]


def run_spec(block: Block) -> RunSpec:
    """Parse ``test[: session | exit N ... | output "TEXT"]`` (fails naming the block on anything else)."""
    rest = block.marker.removeprefix("test").strip().removeprefix(":").strip()
    session, exits, output = False, {0}, None
    tokens = shlex.split(rest)
    i = 0
    while i < len(tokens):
        tok = tokens[i]
        if tok == "session":
            session = True
            i += 1
        elif tok == "exit":
            j = i + 1
            codes = set()
            while j < len(tokens) and tokens[j].isdigit():
                codes.add(int(tokens[j]))
                j += 1
            assert codes, f"{block.where}: 'exit' needs status numbers"
            exits, i = codes, j
        elif tok == "output" and i + 1 < len(tokens):
            output, i = tokens[i + 1], i + 2
        else:
            raise AssertionError(f"{block.where}: unknown test marker option {tok!r} in {block.marker!r}")
    return RunSpec(session, frozenset(exits), output)


def runnable(pages: list[Path] = GUIDE_PAGES) -> list[Block]:
    return [b for p in pages for b in marked_blocks(p) if b.lang == "sh" and re.match(r"test\b", b.marker)]


def test_every_shell_block_is_run_or_says_why_not() -> None:
    """A ```sh block without a marker would be a command no test runs."""
    seen = 0
    for page in GUIDE_PAGES:
        text = page.read_text(encoding="utf-8")
        marked = {b.line for b in marked_blocks(page)}
        for m in _FENCE.finditer(text):
            if m.group("lang") != "sh":
                continue
            seen += 1
            line = text.count("\n", 0, m.start("lang")) + 1
            where = f"{page.relative_to(REPO)}:{line}"
            assert line in marked, f"{where}: a ```sh block needs <!-- test --> or <!-- not run: REASON -->"
        for b in marked_blocks(page):
            if b.lang != "sh":
                continue
            if b.marker.startswith("not run"):
                reason = b.marker.removeprefix("not run").strip(" :")
                assert len(reason) > 10, f"{b.where}: 'not run' needs its reason"
            else:
                assert re.match(r"test\b", b.marker), f"{b.where}: unknown marker {b.marker!r}"
                run_spec(b)
                for cmd in b.commands():
                    assert shlex.split(cmd)[0] == "rig", f"{b.where}: {cmd!r} is not a rig command"
    assert seen >= 10


def test_guide_pages_are_in_the_mkdocs_nav() -> None:
    nav = (REPO / "mkdocs.yml").read_text(encoding="utf-8")
    for page in GUIDE_PAGES:
        rel = page.relative_to(DOCS).as_posix()
        assert f": {rel}" in nav, f"docs/{rel} is not in mkdocs.yml's nav"


def test_guide_builds_with_mkdocs_strict(tmp_path: Path) -> None:
    pytest.importorskip("mkdocs", reason="mkdocs is a dev dependency (pip install -e '.[dev]')")
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(tmp_path / "site")],
                          cwd=REPO, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert (tmp_path / "site" / "guide" / "hardware" / "index.html").is_file()


# --- the shell commands, against a simulated session -------------------------------------------


def _rig(cmd: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    args = shlex.split(cmd)
    assert args[0] == "rig", cmd
    env = {**os.environ, "PYTHONPATH": str(REPO), "NO_COLOR": "1", "COLUMNS": "200"}
    env.pop("RIG_LIVE_TOKEN", None)
    return subprocess.run([sys.executable, "-m", "rig", *args[1:]], cwd=cwd, capture_output=True, text=True,
                          timeout=COMMAND_TIMEOUT_S, env=env, stdin=subprocess.DEVNULL)


def _check(block: Block, spec: RunSpec, cmd: str, cwd: Path) -> None:
    proc = _rig(cmd, cwd)
    out = proc.stdout + proc.stderr
    assert proc.returncode in spec.exits, (
        f"{block.where}: `{cmd}` exited {proc.returncode}, expected {sorted(spec.exits)}:\n{out[-3000:]}")
    if spec.output is not None:
        assert spec.output in out, f"{block.where}: `{cmd}` did not print {spec.output!r}:\n{out[-3000:]}"


def _prepare(wd: Path) -> None:
    """sim.toml (the shipped simulated car), car.toml (the car template) and the roles files."""
    wd.mkdir(parents=True)
    shutil.copy(REPO / "rig" / "examples" / "sim.toml", wd / "sim.toml")
    shutil.copytree(REPO / "rig" / "examples" / "roles", wd / "roles")
    shutil.copy(REPO / "examples" / "car-template.toml", wd / "car.toml")
    shutil.copytree(REPO / "examples" / "roles", wd / "roles", dirs_exist_ok=True)


def _record_guide_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The working directory with ``sessions/day1`` recorded by the guide's own session block, once per test run.

    The pages' commands run in copies of it, in more than one unit of work (tests/conftest.py), so under
    pytest-xdist the first worker to need it records it (in the run's temporary directory, which every worker
    of the run shares) while a file lock keeps the others waiting; a failed recording is kept as a marker, so
    the others fail at once with its message instead of recording again."""
    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    done, failed = shared / "guide-session", shared / "guide-session.failed"
    with open(shared / "guide-session.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if failed.exists():
                raise AssertionError(f"the guide's session block failed in another test: {failed.read_text()}")
            if not done.is_dir():
                wd = shared / "guide-session.partial"
                shutil.rmtree(wd, ignore_errors=True)
                _prepare(wd)
                sessions = [b for b in runnable() if run_spec(b).session]
                try:
                    assert len(sessions) == 1, (
                        f"exactly one <!-- test: session --> block, found {[b.where for b in sessions]}")
                    block = sessions[0]
                    for cmd in block.commands():
                        _check(block, run_spec(block), cmd, wd)
                    assert sorted(p.name for p in (wd / "sessions").glob("day1.*.mcap")), (
                        "the session block recorded nothing")
                except BaseException as exc:
                    failed.write_text(f"{type(exc).__name__}: {exc}"[-3000:], encoding="utf-8")
                    raise
                wd.rename(done)
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    return done


def _copy_of(session: Path, wd: Path) -> Path:
    shutil.copytree(session, wd, dirs_exist_ok=True)
    return wd


@pytest.fixture(scope="module")
def guide_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _record_guide_session(tmp_path_factory)


@pytest.fixture(scope="module")
def workdir(guide_session: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """sim.toml, car.toml and sessions/day1, recorded by the guide's own session block: the working directory
    of the pages run in order, one after the other."""
    return _copy_of(guide_session, tmp_path_factory.mktemp("guide"))


PAGES_ALONE = ("guide/live-and-exports.md",)
"""Pages whose commands read the recorded session but nothing another page writes: each runs in a copy of its
own, as a unit of work of its own (tests/conftest.py), beside the pages run in order (the procedure writes the
calibration the report's page reads)."""

PAGES_WITH_COMMANDS = [p for p in GUIDE_PAGES if any(not run_spec(b).session for b in runnable([p]))]
PAGES_IN_ORDER = [p for p in PAGES_WITH_COMMANDS if p.relative_to(DOCS).as_posix() not in PAGES_ALONE]


def _run_page(page: Path, wd: Path) -> None:
    """Every runnable command of the page, in order, in ``wd``."""
    ran = 0
    for block in runnable([page]):
        spec = run_spec(block)
        if spec.session:
            continue  # recorded by the fixture
        for cmd in block.commands():
            _check(block, spec, cmd, wd)
            ran += 1
    assert ran > 0


@pytest.mark.timeout(3000)
def test_the_guide_session_block_records(guide_session: Path) -> None:
    """The session block's commands (their exit statuses and output are checked as they run) and its file. A
    test of its own, so the recording is a unit of work of its own that starts first (tests/conftest.py)."""
    parts = sorted((guide_session / "sessions").glob("day1.*.mcap"))
    assert parts and all(p.stat().st_size > 1_000_000 for p in parts), parts


def test_the_pages_run_alone_exist_and_run_commands() -> None:
    names = {p.relative_to(DOCS).as_posix() for p in PAGES_WITH_COMMANDS}
    assert set(PAGES_ALONE) <= names, sorted(set(PAGES_ALONE) - names)


@pytest.mark.timeout(3000)
@pytest.mark.parametrize("page", PAGES_IN_ORDER, ids=lambda p: p.relative_to(DOCS).as_posix())
def test_guide_commands_run(page: Path, workdir: Path) -> None:
    """Every runnable command of the page, in order, in the shared working directory."""
    _run_page(page, workdir)


@pytest.mark.timeout(3000)
@pytest.mark.parametrize("page", [DOCS / p for p in PAGES_ALONE], ids=lambda p: p.relative_to(DOCS).as_posix())
def test_guide_page_alone(page: Path, guide_session: Path, tmp_path: Path) -> None:
    """Every runnable command of the page, in order, in a copy of the recorded working directory of its own."""
    _run_page(page, _copy_of(guide_session, tmp_path / "guide"))


# --- the NovAtel commands the guide lists --------------------------------------------------------


def novatel_blocks() -> list[tuple[Block, str, str]]:
    out = []
    for page in GUIDE_PAGES:
        for b in marked_blocks(page):
            m = re.fullmatch(r"novatel-commands:\s*(\S+)\s+(\S+)", b.marker)
            if m:
                out.append((b, m.group(1), m.group(2)))
    return out


def test_listed_novatel_commands_are_what_the_driver_sends() -> None:
    blocks = novatel_blocks()
    assert blocks, "the guide lists no NovAtel commands"
    listed: dict[tuple[str, str], list[str]] = {}
    for block, config, receiver in blocks:
        listed[(config, receiver)] = block.commands()
    for config in {c for c, _r in listed}:
        cfg = load_session(REPO / config)
        assert {r for c, r in listed if c == config} == {rc.name for rc in cfg.receivers}, (
            f"the guide lists the commands of some receivers of {config} only")
        for rc in cfg.receivers:
            assert listed[(config, rc.name)] == list(receiver_commands(rc)), f"{config} {rc.name}"


def _response(port: serial.Serial, framer: Framer, line: str, timeout_s: float = 10.0) -> str:
    """Send one command line; the text of the receiver's response to it."""
    port.write(line.encode("ascii") + b"\r\n")
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        data = port.read(65536)
        for frame in framer.feed(data) if data else framer.flush():
            if frame.kind is FrameKind.RESPONSE:
                return frame.raw.decode("ascii", "replace").strip()
    raise AssertionError(f"no response to {line!r} within {timeout_s} s")


@pytest.fixture
def timebase() -> SimTimeBase:
    return SimTimeBase.from_gps_start(2400, 345600.0, leap_seconds=18)


@pytest.fixture
def sim_receivers(timebase: SimTimeBase) -> Iterator[dict[str, SimBase | SimRover]]:
    clock = timebase.make_clock(speed=1.0)
    assert isinstance(clock, ScaledClock)
    truth = simulate(make_scenario("straight", speed_kmh=30.0, duration_s=30.0), rate_hz=20.0)
    base = SimBase("base", position=(48.0, 9.0, 400.0), timebase=timebase, clock=clock)
    rovers = {name: SimRover(name, truth=truth, lever_arm=(0.5, 0.0, 1.0), timebase=timebase, clock=clock,
                             baud=460800) for name in ("rover_a", "rover_b")}
    devices: dict[str, SimBase | SimRover] = {"base": base, **rovers}
    started: list[SimBase | SimRover] = []
    try:
        for dev in devices.values():
            dev.start()
            started.append(dev)
        yield devices
    finally:
        for dev in started:
            dev.stop()


NOT_SIMULATED: frozenset[str] = frozenset()
"""Listed commands the simulated rover refuses because it does not generate that log (RAWEPHEM): it
must answer with the receiver's own refusal, so this set has to shrink when the simulator learns one."""


def test_simulated_receivers_answer_ok_to_each_listed_command(sim_receivers: dict[str, SimBase | SimRover]) -> None:
    checked = 0
    for block, config, receiver in novatel_blocks():
        assert config == "examples/car-template.toml", f"{block.where}: no simulated receivers for {config}"
        cfg = load_session(REPO / config)
        rc = next(r for r in cfg.receivers if r.name == receiver)
        sim = sim_receivers[receiver]
        with serial.Serial(sim.port_path, rc.baud, timeout=0.05) as port:
            framer = Framer()
            for cmd in block.commands():
                answer = _response(port, framer, cmd)
                if cmd in NOT_SIMULATED:
                    assert answer == "<ERROR:Invalid Message. Field = 3", f"{cmd!r} is simulated now: {answer!r}"
                    continue
                assert answer.startswith("<OK"), f"{block.where}: {receiver} answered {answer!r} to {cmd!r}"
                checked += 1
    assert checked >= 20

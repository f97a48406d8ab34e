"""The part scanner: truncation anywhere, corruption, part discovery; in-place finalizing; the README table."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

import rig.core.topics as T  # noqa: N812 - short alias used throughout the tests
from rig.core.topics import topics_markdown
from rig.store import ProblemKind, Recorder, finalize_in_place, find_parts, scan_part, session_base
from tests.recorder.helpers import T0, options, read_with_mcap
from vsccore.errors import SessionFileError

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def small_part(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("small")
    rec = Recorder(d, "s", options=options(chunk_size=1500))
    with rec:
        src = rec.source("g", maxsize=10_000)
        for i in range(400):
            src.put(T.gnss_raw("g"), T0 + i, T0 + i, i.to_bytes(4, "little") * 10)
    return d / "s.000.mcap"


def test_scan_matches_mcap_reader(small_part: Path) -> None:
    scan = scan_part(small_part)
    assert scan.problem is None and scan.finalized and scan.data_end_found
    msgs, summary = read_with_mcap(small_part)
    assert summary is not None
    assert scan.message_count == summary.statistics.message_count == len(msgs)
    assert len(scan.chunks) == summary.statistics.chunk_count > 10
    g = scan.topics[T.gnss_raw("g")]
    assert g.data == [d for topic, _s, _l, _p, d in msgs if topic == T.gnss_raw("g")]
    assert g.sequence == list(range(400))
    only_events = scan_part(small_part, want=lambda t: t == T.TOPIC_EVENTS)
    assert set(only_events.topics) == {T.TOPIC_EVENTS}


def test_truncation_at_any_offset_gives_a_prefix(small_part: Path, tmp_path: Path) -> None:
    data = small_part.read_bytes()
    full = [int.from_bytes(d[:4], "little") for d in scan_part(small_part).topics[T.gnss_raw("g")].data]
    cut_file = tmp_path / "cut.mcap"
    previous = -1
    for cut in range(9, len(data), max(1, len(data) // 150)):
        cut_file.write_bytes(data[:cut])
        scan = scan_part(cut_file)
        assert scan.problem_kind is ProblemKind.TRUNCATED, (cut, scan.problem)
        tm = scan.topics.get(T.gnss_raw("g"))
        got = [] if tm is None else [int.from_bytes(d[:4], "little") for d in tm.data]
        assert got == full[: len(got)]
        assert len(got) >= previous  # never fewer messages from a longer prefix
        previous = len(got)
        assert scan.data_end <= cut


def test_zero_filled_tail_is_a_truncation(small_part: Path, tmp_path: Path) -> None:
    data = small_part.read_bytes()
    f = tmp_path / "zeros.mcap"
    f.write_bytes(data[: len(data) // 2] + b"\0" * 8192)
    scan = scan_part(f)
    assert scan.problem_kind is ProblemKind.TRUNCATED and "zero-filled" in (scan.problem or "")


def test_damaged_chunk_is_corruption_not_truncation(small_part: Path, tmp_path: Path) -> None:
    scan = scan_part(small_part)
    chunk = scan.chunks[3]
    data = bytearray(small_part.read_bytes())
    mid = chunk.offset + chunk.length - 20
    data[mid] ^= 0xFF
    f = tmp_path / "bad.mcap"
    f.write_bytes(bytes(data))
    bad = scan_part(f)
    assert bad.problem_kind is ProblemKind.CORRUPT
    assert f"offset {chunk.offset}" in (bad.problem or "")
    # every other chunk, before and after the damaged one, is kept
    assert [c.offset for c in bad.chunks] == [c.offset for c in scan.chunks if c.offset != chunk.offset]
    assert [d.chunks for d in bad.damage] == [(3,)]
    with pytest.raises(SessionFileError, match=r"bad\.mcap"):
        bad.check(allow_truncated=True)
    bad.check(allow_truncated=True, allow_damaged=True)
    f.write_bytes(b"not an mcap file at all")
    with pytest.raises(SessionFileError, match="not an MCAP file"):
        scan_part(f)


def test_finalize_in_place_then_mcap_reads_it(small_part: Path, tmp_path: Path) -> None:
    data = small_part.read_bytes()
    f = tmp_path / "crashed.mcap"
    f.write_bytes(data[: int(len(data) * 0.6)])
    before = scan_part(f)
    report = finalize_in_place(f)
    assert report.finalized and not report.was_finalized and report.messages == before.message_count
    msgs, summary = read_with_mcap(f)
    assert summary is not None and len(msgs) == before.message_count
    assert scan_part(f).finalized
    # a finalized part is left alone
    again = finalize_in_place(f)
    assert again.was_finalized and f.stat().st_size == len(f.read_bytes())


def test_find_parts(tmp_path: Path) -> None:
    for i in (0, 1, 2):
        (tmp_path / f"run.{i:03d}.mcap").write_bytes(b"")
    (tmp_path / "run2.000.mcap").write_bytes(b"")
    expected = [tmp_path / f"run.{i:03d}.mcap" for i in range(3)]
    assert find_parts(tmp_path / "run") == expected
    assert find_parts(tmp_path / "run.001.mcap") == expected
    assert session_base(tmp_path / "run.001.mcap") == tmp_path / "run"
    with pytest.raises(SessionFileError, match="expected one session"):
        find_parts(tmp_path)
    (tmp_path / "run.001.mcap").unlink()
    with pytest.raises(SessionFileError, match=r"run\.001\.mcap: part 1 of session run is missing"):
        find_parts(tmp_path / "run")
    with pytest.raises(SessionFileError, match="no session parts"):
        find_parts(tmp_path / "other")
    lone = tmp_path / "export.mcap"
    lone.write_bytes(b"")
    assert find_parts(lone) == [lone]


def test_readme_topics_table_matches_the_module() -> None:
    readme = (REPO / "README.md").read_text()
    assert "## Topics" in readme
    section = readme.split("\n## Topics", 1)[1].split("\n## ", 1)[0]
    table = "\n".join(line for line in section.splitlines() if line.startswith("|"))
    stale = "README Topics table is stale: regenerate it from rig.core.topics.topics_markdown()"
    assert table + "\n" == topics_markdown(), stale
    for spec in T.TOPICS:
        assert f"`{spec.pattern}`" in table


def test_recover_refuses_to_overwrite(small_part: Path, tmp_path: Path) -> None:
    from rig.store import recover

    src = tmp_path / "x.000.mcap"
    shutil.copy(small_part, src)
    r = recover(src)
    assert r.was_finalized and r.finalized
    with pytest.raises(SessionFileError, match="already exists"):
        recover(src)
    with pytest.raises(SessionFileError, match="must differ"):
        recover(src, src)

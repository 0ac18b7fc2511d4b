"""Replay reader: timing from reader start, bad files refused up front, and record."""

from __future__ import annotations

import asyncio
import json
import math
import time
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from lupin.cli import main
from lupin.pad import PadFrame, PadReader
from lupin_adapters.pads.replay import ReplayError, ReplayReader, parse_replay, record


def write(path: Path, *lines: object) -> Path:
    path.write_text("".join((ln if isinstance(ln, str) else json.dumps(ln)) + "\n" for ln in lines))
    return path


def frame_line(t: float, lb: int = 0, fwd: float = 0.0) -> dict[str, object]:
    return {"t": t, "axes": [0.0, fwd, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0], "buttons": [0] * 6 + [lb]}


async def collect(reader: ReplayReader) -> list[tuple[float, PadFrame | None]]:
    start = time.monotonic()
    return [(time.monotonic() - start, item) async for item in reader.frames()]


async def test_frames_play_at_their_time_from_reader_start(tmp_path: Path) -> None:
    path = write(
        tmp_path / "drive.jsonl",
        "# LB then forward, then an unplug and a replug",
        frame_line(0.0),
        frame_line(0.1, lb=1),
        "",
        frame_line(0.2, lb=1, fwd=1.0),
        {"t": 0.3, "event": "disconnect"},
        {"t": 0.4, "event": "connect"},
        frame_line(0.4),
    )
    reader = ReplayReader(str(path), layout="xbox-bluetooth")
    await asyncio.sleep(0.2)  # construction is not the start: t counts from frames()
    got = await collect(reader)
    assert [item is None for _, item in got] == [False, False, False, True, False]
    for (at, _), want in zip(got, (0.0, 0.1, 0.2, 0.3, 0.4), strict=True):
        assert want - 0.005 <= at <= want + 0.08
    first = got[1][1]
    assert first is not None and first.buttons[6] == 1 and first.axes[4] == 1.0


def test_nan_axes_are_replayed_as_the_pad_reported_them(tmp_path: Path) -> None:
    path = tmp_path / "nan.jsonl"
    path.write_text('{"t": 0, "axes": [NaN, Infinity], "buttons": []}\n')
    entry = ReplayReader(str(path), layout="ds4").entries[0]
    assert math.isnan(entry.axes[0]) and entry.axes[1] == math.inf


@pytest.mark.parametrize(
    ("line", "needle"),
    [
        ("{not json", "Expecting property name"),
        ('{"t": 1, "axes": []}', "exactly t, axes, buttons"),
        ('{"t": -1, "axes": [], "buttons": []}', "t must be a finite number"),
        ('{"t": true, "axes": [], "buttons": []}', "t must be a finite number"),
        ('{"t": 1, "axes": ["x"], "buttons": []}', "axes must be a list of numbers"),
        ('{"t": 1, "axes": [], "buttons": [1.5]}', "buttons must be a list of integers"),
        ('{"t": 1, "event": "explode"}', "event one of"),
        ("[1, 2]", "expected a JSON object"),
        ('{"t": 0.05, "axes": [], "buttons": []}', "t goes backwards"),
    ],
)
def test_bad_line_is_an_error_naming_the_line_before_anything_plays(
    tmp_path: Path, line: str, needle: str
) -> None:
    path = write(tmp_path / "bad.jsonl", frame_line(0.0), frame_line(0.1), line)
    with pytest.raises(ReplayError) as info:
        ReplayReader(str(path), layout="xbox-usb")
    assert str(info.value).startswith(f"{path}:3: ")
    assert needle in str(info.value)


def test_frame_while_disconnected_and_empty_files_are_refused(tmp_path: Path) -> None:
    path = write(tmp_path / "a.jsonl", {"t": 0, "event": "disconnect"}, frame_line(1.0))
    with pytest.raises(ReplayError, match=":2: a frame while disconnected"):
        parse_replay(path.read_text(), str(path))
    with pytest.raises(ReplayError, match="no frames"):
        parse_replay("\n# only a comment\n", "empty.jsonl")
    with pytest.raises(ReplayError, match="cannot read"):
        ReplayReader(str(tmp_path / "missing.jsonl"), layout="xbox-usb")


class ScriptedReader:
    name, transport = "scripted", "test"

    def __init__(self, items: list[PadFrame | None], forever: bool = False) -> None:
        self.items, self.forever, self.closed = items, forever, False

    async def frames(self) -> AsyncIterator[PadFrame | None]:
        for item in self.items:
            await asyncio.sleep(0.01)
            yield item
        if self.forever:
            await asyncio.Event().wait()

    async def close(self) -> None:
        self.closed = True


async def test_record_writes_a_replayable_file(tmp_path: Path) -> None:
    items: list[PadFrame | None] = [
        PadFrame(0, (0.0, 0.5), (0, 1)),
        None,
        None,
        PadFrame(0, (1.0, -1.0), (1, 0)),
    ]
    reader = ScriptedReader(items)
    out = tmp_path / "rec.jsonl"
    reader_proto: PadReader = reader
    assert await record(reader_proto, out, None) == 2
    assert reader.closed
    entries = parse_replay(out.read_text(), str(out))
    assert [e.event for e in entries] == [None, "disconnect", "connect", None]
    assert entries[0].axes == (0.0, 0.5) and entries[3].buttons == (1, 0)
    assert entries[0].t < entries[1].t <= entries[3].t


async def test_record_stops_after_seconds(tmp_path: Path) -> None:
    reader = ScriptedReader([PadFrame(0, (0.0,), (0,))], forever=True)
    start = time.monotonic()
    assert await record(reader, tmp_path / "rec.jsonl", 0.2) == 1
    assert 0.15 < time.monotonic() - start < 1.0


def test_pad_record_cli_round_trip(tmp_path: Path) -> None:
    src = write(tmp_path / "in.jsonl", frame_line(0.0), frame_line(0.05, lb=1))
    out = tmp_path / "out.jsonl"
    assert main(["pad-record", str(out), "--pad", f"replay:{src}", "--seconds", "2"]) == 0
    entries = parse_replay(out.read_text(), str(out))
    assert [e.buttons[6] for e in entries] == [0, 1]

"""An MCAP file read as arrays (:func:`mcap_stream.batches`) against the same file read
message by message (:func:`mcap_stream.messages`): the same messages, bytes, log times
and order, the same damage at the same place.

The files are written by the ``mcap`` package's writer (not edgerv's), in every layout
it has: chunks of any size compressed with zstd, lz4 or not at all, with and without
message indexes, no chunks at all; log times out of order within and across chunks;
cut at random bytes; message indexes that lie.
"""

from __future__ import annotations

import io
import random
from pathlib import Path
from typing import Any

import pytest
from mcap.writer import CompressionType, IndexType, Writer

from edgerv.core import mcap_stream

TOPICS = ["/a", "chatter", "/skipped", "/b"]


def write(rng: random.Random, n: int, **options: Any) -> bytes:
    """``n`` messages on four channels, log times mostly rising (now and then one from
    the past), payloads of random lengths."""
    out = io.BytesIO()
    w = Writer(out, **options)
    w.start("ros2", "test")
    schema = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
    ids = [w.register_channel(t, "cdr", schema) for t in TOPICS]
    t = 1_000
    for i in range(n):
        t += rng.choice([0, 1, 5, 100])
        at = t - rng.randint(1, 400) if rng.random() < 0.05 else t
        data = bytes(rng.getrandbits(8) for _ in range(rng.choice([0, 1, 8, 12, 31])))
        w.add_message(rng.choice(ids), log_time=at, data=data, publish_time=at, sequence=i)
    w.finish()
    return out.getvalue()


def wanted(channel: mcap_stream.Channel) -> str | None:
    return None if channel.topic == "/skipped" else channel.topic.lstrip("/")


def read_rows(path: Path, starts: Any) -> tuple[list[tuple[str, int, bytes]], str | None]:
    got: list[tuple[str, int, bytes]] = []
    try:
        for row in mcap_stream.messages(path, wanted, starts=starts):
            got.append(row)
    except mcap_stream.Cut as exc:
        return got, str(exc)
    return got, None


def read_batches(
    path: Path, starts: Any, size: int
) -> tuple[list[tuple[str, int, bytes]], str | None]:
    got: list[tuple[str, int, bytes]] = []
    try:
        for batch, topics in mcap_stream.batches(path, wanted, starts=starts, size=size):
            for i in range(len(batch)):
                data = batch.buffer[int(batch.start[i]) : int(batch.end[i])].tobytes()
                got.append((topics[int(batch.channel[i])], int(batch.log_time[i]), data))
    except mcap_stream.Cut as exc:
        return got, str(exc)
    return got, None


LAYOUTS = [
    {},
    {"chunk_size": 200},
    {"chunk_size": 64, "compression": CompressionType.LZ4},
    {"chunk_size": 300, "compression": CompressionType.NONE},
    {"chunk_size": 250, "index_types": IndexType.NONE},  # no message index: walked
    {"use_chunking": False},
    {"chunk_size": 128, "repeat_channels": False},
]


@pytest.mark.parametrize("layout", range(len(LAYOUTS)))
@pytest.mark.parametrize("seed", range(6))
def test_batches_hold_the_messages_read_one_by_one(tmp_path: Path, layout: int, seed: int) -> None:
    rng = random.Random(seed * 31 + layout)
    path = tmp_path / "run.mcap"
    path.write_bytes(write(rng, rng.randint(0, 600), **LAYOUTS[layout]))
    summary = mcap_stream.summary(path)
    for starts in (summary.starts if summary else None, None):
        rows = read_rows(path, starts)
        assert rows[1] is None
        for size in (1, 7, mcap_stream.BATCH_MESSAGES):
            assert read_batches(path, starts, size) == rows


@pytest.mark.parametrize("seed", range(8))
def test_a_file_cut_anywhere_gives_what_was_read_before_the_cut(tmp_path: Path, seed: int) -> None:
    rng = random.Random(seed)
    whole = write(rng, 300, chunk_size=rng.choice([100, 400, 2000]))
    path = tmp_path / "cut.mcap"
    for _ in range(12):
        path.write_bytes(whole[: rng.randint(0, len(whole) - 1)])
        rows, damage = read_rows(path, None)
        assert read_batches(path, None, rng.choice([5, 1000])) == (rows, damage)


def message_index_spans(data: bytes) -> list[tuple[int, int]]:
    """Where each message index record's body is in the file."""
    spans, pos = [], len(mcap_stream.MAGIC)
    while pos + 9 <= len(data):
        op, length = data[pos], int.from_bytes(data[pos + 1 : pos + 9], "little")
        if op == 0x07:
            spans.append((pos + 9, pos + 9 + length))
        if op == 0x02:
            break
        pos += 9 + length
    return spans


@pytest.mark.parametrize("seed", range(10))
def test_message_indexes_that_lie_change_nothing(tmp_path: Path, seed: int) -> None:
    """An index whose offsets or counts are wrong (a damaged or hostile file): the chunk
    is walked instead, or its lies name whole message records, never other bytes."""
    rng = random.Random(seed)
    whole = bytearray(write(rng, 400, chunk_size=300, compression=CompressionType.NONE))
    path = tmp_path / "run.mcap"
    path.write_bytes(whole)
    expected = read_rows(path, None)
    spans = message_index_spans(bytes(whole))
    assert spans
    for _ in range(5):
        start, end = rng.choice(spans)
        at = rng.randrange(start, end)
        whole[at] = rng.getrandbits(8)
        path.write_bytes(whole)
        rows = read_rows(path, None)
        assert rows == expected  # the row reader never reads the indexes
        assert read_batches(path, None, 64) == rows


def test_an_index_that_names_another_message_of_the_chunk_is_not_followed(tmp_path: Path) -> None:
    """An index pointing one message at another's record (both whole records): the batch
    may not give a message twice and lose one, so the chunk is walked."""
    data = bytearray(write(random.Random(3), 50, compression=CompressionType.NONE))
    spans = message_index_spans(bytes(data))
    start, _ = spans[0]
    # the first pair's offset (after channel id u16 and the array's u32 length, the time)
    first = start + 2 + 4 + 8
    second = first + 16
    data[second : second + 8] = data[first : first + 8]
    path = tmp_path / "dup.mcap"
    path.write_bytes(data)
    assert read_batches(path, None, 64) == read_rows(path, None)


def test_an_index_that_leaves_a_message_out_is_not_followed(tmp_path: Path) -> None:
    """An index one entry short (its length says so, consistently): the message it left
    out is still read, from the walk of the chunk."""
    data = bytearray(write(random.Random(4), 80, compression=CompressionType.NONE))
    start, _ = message_index_spans(bytes(data))[0]
    n = int.from_bytes(data[start + 2 : start + 6], "little")
    assert n >= 32
    data[start + 2 : start + 6] = (n - 16).to_bytes(4, "little")
    path = tmp_path / "short.mcap"
    path.write_bytes(data)
    assert read_batches(path, None, 64) == read_rows(path, None)


def test_indexes_are_used_where_they_hold(tmp_path: Path) -> None:
    """The usual file's chunks are read from their message indexes, not walked."""
    path = tmp_path / "run.mcap"
    path.write_bytes(write(random.Random(5), 500, chunk_size=400))
    walked: list[int] = []
    real = mcap_stream._walk

    def spy(*args: Any) -> Any:
        walked.append(1)
        return real(*args)

    mcap_stream._walk = spy  # type: ignore[assignment]
    try:
        rows = read_batches(path, None, 64)
    finally:
        mcap_stream._walk = real  # type: ignore[assignment]
    assert rows == read_rows(path, None)
    assert len(walked) <= 1  # the first chunk holds the channel records: walked

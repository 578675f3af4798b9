"""Damage-tolerant reading of MCAP records, one chunk at a time.

A recording damaged in transit (flipped bytes, a cut) must give back every frame that is still
readable. MCAP lends itself to that: messages live in chunks, each compressed on its own with
the CRC of its uncompressed bytes, and softforce's writer puts one frame in each chunk. So a
chunk that fails to read (bad record framing, undecodable zstd data, CRC mismatch) is skipped
and counted, and reading goes on with the next one. Two paths:

- indexed_messages: a finished file whose summary section passes its CRC; chunks are found
  through the chunk index and read in log-time order.
- scanned_records (mcap_scan.py): no summary, or a damaged one; the data section is walked
  record by record, re-synchronising on the next chunk header after damaged framing.

What was lost is collected in a Damage and reported once, as one RecordingWarning.
"""

from __future__ import annotations

import io
import struct
import warnings
import zlib
from array import array
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO, Protocol

import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    Footer,
    McapRecord,
    Message,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
)
from mcap.stream_reader import MAGIC_SIZE, breakup_chunk
from mcap.summary import Summary


class RecordingWarning(UserWarning):
    """A recording was read only in part: truncated, damaged, or with incomplete frames."""


# What damaged bytes raise inside the mcap library and zstandard: short reads, impossible
# lengths, CRC mismatches (a ValueError), undecodable data, strings that are not UTF-8.
DAMAGE_ERRORS = (
    McapError, struct.error, ValueError, EOFError, zstandard.ZstdError, KeyError, IndexError,
    OverflowError, MemoryError,
)
# A chunk claiming more uncompressed bytes than this is damaged: a 1280x720 RGB-D frame is
# 4.6 MB, and zstandard would otherwise allocate whatever a flipped size field asks for.
MAX_CHUNK_BYTES = 1 << 30
RECORD_HEAD = struct.Struct("<BQ")  # opcode, record length
_FOOTER_BYTES = RECORD_HEAD.size + 8 + 8 + 4
KNOWN_OPCODES = {int(op) for op in Opcode}
_SUMMARY_RECORDS = {
    Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel, Opcode.CHUNK_INDEX: ChunkIndex,
    Opcode.STATISTICS: Statistics, Opcode.METADATA_INDEX: MetadataIndex,
}


class Damage:
    """What a damaged recording lost: skipped chunks (and their frames), skipped bytes, a cut."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.chunk_offsets: list[int] = []
        self.frames = 0
        self.frames_unknown = False
        self.skipped_bytes: list[tuple[int, int]] = []
        self.cut_at: int | None = None
        self.metadata_lost = 0
        self.moved = 0  # chunks read from elsewhere than where the index says

    def skip_chunk(self, offset: int, frames: int | None) -> None:
        self.chunk_offsets.append(offset)
        self.frames += frames if frames is not None else 1
        self.frames_unknown |= frames is None

    def warn(self) -> None:
        """One RecordingWarning naming everything lost, if anything was."""
        parts = []
        if self.chunk_offsets:
            at = ", ".join(str(offset) for offset in self.chunk_offsets[:3])
            more = ", ..." if len(self.chunk_offsets) > 3 else ""
            frames = f"{'at least ' if self.frames_unknown else ''}{self.frames} frame(s)"
            parts.append(
                f"skipped {frames} in {len(self.chunk_offsets)} damaged chunk(s) "
                f"(at byte {at}{more})"
            )
        if self.skipped_bytes:
            start, end = self.skipped_bytes[0]
            parts.append(f"skipped unreadable bytes {start}-{end}")
        if self.metadata_lost:
            parts.append(f"{self.metadata_lost} unreadable metadata record(s)")
        if self.cut_at is not None:
            parts.append(f"the file ends inside a record at byte {self.cut_at}")
        if self.moved:
            parts.append(f"{self.moved} chunk(s) were not where the index says (found by "
                         "their times)")
        if parts:
            warnings.warn(
                f"{self.path} is damaged or truncated: {'; '.join(parts)}; every other frame "
                "was read",
                RecordingWarning,
                stacklevel=2,
            )


def file_size(stream: BinaryIO) -> int:
    return stream.seek(0, io.SEEK_END)


class ChunkLocator(Protocol):
    def locate(self, times: tuple[int, int]) -> int | None: ...


class ChunkTable:
    """A recording's chunk index as arrays: 24 bytes a chunk rather than the ~1 kB of mcap's
    ChunkIndex objects, so that a long recording's index stays small in memory (a 10-minute
    recording has 18,000 chunks, one per frame)."""

    def __init__(self) -> None:
        self.start_ns, self.end_ns, self.offsets = array("Q"), array("Q"), array("Q")
        # only for chunks holding several log times: to count the frames lost with them
        self.message_index_offsets: dict[int, dict[int, int]] = {}

    def add(self, index: ChunkIndex) -> None:
        if index.message_start_time != index.message_end_time:
            self.message_index_offsets[len(self.offsets)] = dict(index.message_index_offsets)
        self.start_ns.append(index.message_start_time)
        self.end_ns.append(index.message_end_time)
        self.offsets.append(index.chunk_start_offset)

    def __len__(self) -> int:
        return len(self.offsets)

    def groups(self) -> Iterator[list[int]]:
        """Rows in log-time order, chunks whose time ranges overlap grouped together."""
        start = np.frombuffer(self.start_ns, dtype=np.uint64)
        offsets = np.frombuffer(self.offsets, dtype=np.uint64)
        group: list[int] = []
        group_end = -1
        for row in np.lexsort((offsets, start)).tolist():
            if group and self.start_ns[row] > group_end:
                yield group
                group, group_end = [], -1
            group.append(row)
            group_end = max(group_end, self.end_ns[row])
        if group:
            yield group


def trusted_summary(stream: BinaryIO, size: int) -> tuple[Summary | None, ChunkTable, str]:
    """The summary section and its chunk index if the footer and CRC are intact.

    Returns (summary or None, chunks, reason): the reason is "" for a good summary, "no index"
    when the file has none (cut short before it was written, or written without one) and
    "damaged index" when its CRC fails. The summary's own chunk_indexes stay empty.
    """
    chunks = ChunkTable()
    summary, reason = _trusted_summary(stream, size, chunks)
    return summary, chunks, reason


def _trusted_summary(stream: BinaryIO, size: int, chunks: ChunkTable) -> tuple[Summary | None, str]:
    if size < 2 * MAGIC_SIZE + _FOOTER_BYTES:
        return None, "no index"
    stream.seek(size - MAGIC_SIZE - _FOOTER_BYTES)
    footer_bytes = stream.read(_FOOTER_BYTES)
    opcode, length = RECORD_HEAD.unpack_from(footer_bytes)
    if opcode != Opcode.FOOTER or length != _FOOTER_BYTES - RECORD_HEAD.size:
        return None, "no index"
    footer = Footer.read(ReadDataStream(io.BytesIO(footer_bytes[RECORD_HEAD.size :])))
    footer_start = size - MAGIC_SIZE - _FOOTER_BYTES
    if footer.summary_start == 0:
        return None, "no index"
    if not MAGIC_SIZE <= footer.summary_start <= footer_start:
        return None, "damaged index"
    stream.seek(footer.summary_start)
    section = stream.read(footer_start - footer.summary_start)
    crc = zlib.crc32(footer_bytes[:-4], zlib.crc32(section))  # the footer's fields count too
    if footer.summary_crc != 0 and crc != footer.summary_crc:
        return None, "damaged index"
    summary = Summary()
    try:
        for record in _records_in(section):
            _add_to_summary(summary, record, chunks)
    except DAMAGE_ERRORS:
        return None, "damaged index"
    return summary, ""


def salvaged_summary(stream: BinaryIO, size: int) -> Summary:
    """Whatever records of a damaged summary section read before the damage (for channels)."""
    summary = Summary()
    if size < 2 * MAGIC_SIZE + _FOOTER_BYTES:
        return summary
    footer_start = size - MAGIC_SIZE - _FOOTER_BYTES
    stream.seek(footer_start)
    footer_bytes = stream.read(_FOOTER_BYTES)
    try:
        footer = Footer.read(ReadDataStream(io.BytesIO(footer_bytes[RECORD_HEAD.size :])))
        if MAGIC_SIZE <= footer.summary_start < footer_start:
            stream.seek(footer.summary_start)
            for record in _records_in(stream.read(footer_start - footer.summary_start)):
                _add_to_summary(summary, record, None)
    except DAMAGE_ERRORS:
        pass  # keep what was read before the damage
    return summary


def _add_to_summary(summary: Summary, record: McapRecord, chunks: ChunkTable | None) -> None:
    if isinstance(record, Schema):
        summary.schemas[record.id] = record
    elif isinstance(record, Channel):
        summary.channels[record.id] = record
    elif isinstance(record, ChunkIndex):
        if chunks is not None:
            chunks.add(record)
    elif isinstance(record, Statistics):
        summary.statistics = record
    elif isinstance(record, MetadataIndex):
        summary.metadata_indexes.append(record)


def _records_in(data: bytes) -> Iterator[McapRecord]:
    """Top-level records of a summary section (the bytes before the footer), up to its end."""
    position = 0
    while position < len(data):
        if position + RECORD_HEAD.size > len(data):
            raise McapError("a summary record is cut short")
        opcode, length = RECORD_HEAD.unpack_from(data, position)
        start, position = position + RECORD_HEAD.size, position + RECORD_HEAD.size + length
        if position > len(data):
            raise McapError("a summary record runs past the footer")
        record = _SUMMARY_RECORDS.get(opcode)
        if record is not None:  # one record's bytes copied at a time, not the section's
            yield record.read(ReadDataStream(io.BytesIO(data[start:position])))


def indexed_messages(
    stream: BinaryIO,
    size: int,
    chunks: ChunkTable,
    channel_ids: set[int],
    damage: Damage,
    finder: ChunkLocator,
) -> Iterator[Message]:
    """Messages of `channel_ids` in log-time order, chunk by chunk; damaged chunks skipped.

    `finder` locates a chunk by its time range when its indexed offset holds something else
    (mcap_scan.ChunkFinder walks the file for that).

    Chunks whose time ranges overlap are read together and merged, so that the messages of one
    log time always come out together; softforce's own chunks never overlap (one frame each).
    """
    for group in chunks.groups():
        messages: list[Message] = []
        for row in group:
            try:
                records = _indexed_chunk(stream, size, chunks, row, finder, damage)
            except DAMAGE_ERRORS:
                damage.skip_chunk(chunks.offsets[row], _frames_in(stream, size, chunks, row))
                continue
            messages += [
                r for r in records if isinstance(r, Message) and r.channel_id in channel_ids
            ]
        messages.sort(key=lambda message: message.log_time)  # stable: file order within a time
        yield from messages


def _indexed_chunk(
    stream: BinaryIO, size: int, chunks: ChunkTable, row: int, finder: ChunkLocator,
    damage: Damage,
) -> list[McapRecord]:
    """The records of the chunk in `row` of the index; looked for elsewhere in the file when
    its offset holds something else (chunks moved by a bad copy). DAMAGE_ERRORS if damaged."""
    offset, times = chunks.offsets[row], (chunks.start_ns[row], chunks.end_ns[row])
    try:
        chunk = _record_at(stream, size, offset, Opcode.CHUNK, Chunk)
        if (chunk.message_start_time, chunk.message_end_time) != times:
            raise McapError(f"the chunk at byte {offset} is not the one indexed")
    except DAMAGE_ERRORS:
        moved = finder.locate(times)
        if moved is None or moved == offset:
            raise
        chunk = _record_at(stream, size, moved, Opcode.CHUNK, Chunk)
        damage.moved += 1
    return chunk_records(chunk)


def indexed_metadata(
    stream: BinaryIO, size: int, summary: Summary, damage: Damage
) -> dict[str, dict[str, str]]:
    """The metadata records the summary points to, by name; unreadable ones are counted."""
    metadata = {}
    for index in summary.metadata_indexes:
        try:
            record = _record_at(stream, size, index.offset, Opcode.METADATA, Metadata)
        except DAMAGE_ERRORS:
            damage.metadata_lost += 1
            continue
        metadata[record.name] = dict(record.metadata)
    return metadata


def _record_at(stream: BinaryIO, size: int, offset: int, opcode: int, kind: type) -> McapRecord:
    """Read the record of type `kind` at byte `offset`; McapError if something else is there."""
    stream.seek(offset)
    head = stream.read(RECORD_HEAD.size)
    if len(head) < RECORD_HEAD.size:
        raise McapError(f"no record at byte {offset}")
    found, length = RECORD_HEAD.unpack(head)
    if found != opcode or offset + RECORD_HEAD.size + length > size:
        raise McapError(f"no {kind.__name__} record at byte {offset}")
    return kind.read(ReadDataStream(io.BytesIO(stream.read(length))))


def chunk_records(chunk: Chunk) -> list[McapRecord]:
    """The records inside a chunk, its CRC checked; a DAMAGE_ERRORS exception if damaged."""
    if chunk.uncompressed_size > MAX_CHUNK_BYTES:
        raise McapError(f"chunk claims {chunk.uncompressed_size} uncompressed bytes")
    return breakup_chunk(chunk, validate_crc=True)


def _frames_in(stream: BinaryIO, size: int, chunks: ChunkTable, row: int) -> int | None:
    """How many log times (frames) a damaged chunk held, from its message indexes if readable."""
    if row not in chunks.message_index_offsets:
        return 1  # a single log time
    times: set[int] = set()
    try:
        for offset in chunks.message_index_offsets[row].values():
            record = _record_at(stream, size, offset, Opcode.MESSAGE_INDEX, MessageIndex)
            times.update(time for time, _ in record.records)
    except DAMAGE_ERRORS:
        return None
    return len(times) or None

"""Walking an MCAP file's records without trusting its index: for files cut short, with a
damaged summary section, or whose chunks are no longer where the index says.

A record whose length runs past the end of the file, or whose opcode is unknown, makes the walk
look for the next chunk header (re-synchronising) or stop at a truncated end; see
mcap_chunks.py for what a damaged chunk costs and how it is reported.
"""

from __future__ import annotations

import io
import struct
from collections.abc import Iterator
from typing import BinaryIO

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, McapRecord, Message, Metadata, Schema
from mcap.stream_reader import MAGIC_SIZE

from softforce_cli.io.mcap_chunks import (
    DAMAGE_ERRORS,
    KNOWN_OPCODES,
    RECORD_HEAD,
    Damage,
    chunk_records,
)

# Re-synchronising looks for this compression field; a chunk record starts 37 bytes before it
# (opcode 1, length 8, start time 8, end time 8, uncompressed size 8, crc 4).
_CHUNK_MARKERS = (b"\x04\x00\x00\x00zstd", b"\x03\x00\x00\x00lz4")
_CHUNK_HEAD_BYTES = 37


def scanned_records(stream: BinaryIO, size: int, damage: Damage) -> Iterator[McapRecord]:
    """Schema, Channel, Message and Metadata records in file order, read past damage.

    Chunks are opened (CRC checked) and their records yielded; a damaged chunk is skipped. The
    walk ends at the data section's end, the footer, or the end of the file.
    """
    position = MAGIC_SIZE
    while position < size:
        stream.seek(position)
        head = stream.read(RECORD_HEAD.size)
        if len(head) < RECORD_HEAD.size:
            damage.cut_at = position
            return
        opcode, length = RECORD_HEAD.unpack(head)
        end = position + RECORD_HEAD.size + length
        if opcode in (Opcode.DATA_END, Opcode.FOOTER):
            return
        if opcode not in KNOWN_OPCODES or end > size:
            resume = _next_chunk(stream, size, position + 1)
            if resume is None:
                damage.cut_at = position
                return
            damage.skipped_bytes.append((position, resume))
            position = resume
            continue
        content = stream.read(length)
        position = end
        try:
            yield from _top_level(opcode, content, position - RECORD_HEAD.size - length, damage)
        except DAMAGE_ERRORS:
            if opcode == Opcode.METADATA:
                damage.metadata_lost += 1
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE):
                damage.skipped_bytes.append((end - length - RECORD_HEAD.size, end))


def _top_level(opcode: int, content: bytes, offset: int, damage: Damage) -> Iterator[McapRecord]:
    data = ReadDataStream(io.BytesIO(content))
    if opcode == Opcode.CHUNK:
        try:
            chunk = Chunk.read(data)
        except DAMAGE_ERRORS:
            damage.skip_chunk(offset, None)
            return
        try:
            records = chunk_records(chunk)
        except DAMAGE_ERRORS:
            same_time = chunk.message_start_time == chunk.message_end_time
            damage.skip_chunk(offset, 1 if same_time else None)
            return
        yield from records
    elif opcode == Opcode.SCHEMA:
        yield Schema.read(data)
    elif opcode == Opcode.CHANNEL:
        yield Channel.read(data)
    elif opcode == Opcode.MESSAGE:
        yield Message.read(data, len(content))
    elif opcode == Opcode.METADATA:
        yield Metadata.read(data)


def _next_chunk(stream: BinaryIO, size: int, start: int) -> int | None:
    """Offset of the next plausible chunk record at or after `start`, read in 1 MiB blocks."""
    block = 1 << 20
    position = start
    while position < size:
        stream.seek(position)
        data = stream.read(block + 64)
        for marker in _CHUNK_MARKERS:
            found = data.find(marker)
            while 0 <= found < block:
                candidate = position + found - _CHUNK_HEAD_BYTES
                if candidate >= start and _is_chunk_head(stream, size, candidate, marker):
                    return candidate
                found = data.find(marker, found + 1)
        position += block
    return None


def _is_chunk_head(stream: BinaryIO, size: int, offset: int, marker: bytes) -> bool:
    """A chunk record at `offset` whose length agrees with its data length field."""
    stream.seek(offset)
    head = stream.read(_CHUNK_HEAD_BYTES + len(marker) + 8)
    if len(head) < _CHUNK_HEAD_BYTES + len(marker) + 8:
        return False
    opcode, length = RECORD_HEAD.unpack_from(head)
    (data_length,) = struct.unpack_from("<Q", head, _CHUNK_HEAD_BYTES + len(marker))
    end = offset + RECORD_HEAD.size + length
    return (
        opcode == Opcode.CHUNK
        and end <= size
        and length == _CHUNK_HEAD_BYTES - RECORD_HEAD.size + len(marker) + 8 + data_length
    )


class ChunkFinder:
    """Where each chunk really is, by its time range: the record headers walked once, the
    first time an indexed offset does not hold its chunk."""

    def __init__(self, stream: BinaryIO, size: int) -> None:
        self.stream, self.size = stream, size
        self._found: dict[tuple[int, int], int] | None = None

    def locate(self, times: tuple[int, int]) -> int | None:
        if self._found is None:
            self._found = self._walk()
        return self._found.get(times)

    def _walk(self) -> dict[tuple[int, int], int]:
        found: dict[tuple[int, int], int] = {}
        position = MAGIC_SIZE
        while position + RECORD_HEAD.size + 16 <= self.size:
            self.stream.seek(position)
            head = self.stream.read(RECORD_HEAD.size + 16)
            opcode, length = RECORD_HEAD.unpack_from(head)
            end = position + RECORD_HEAD.size + length
            if opcode in (Opcode.DATA_END, Opcode.FOOTER):
                break
            if opcode not in KNOWN_OPCODES or end > self.size:
                position = _next_chunk(self.stream, self.size, position + 1)
                if position is None:
                    break
                continue
            if opcode == Opcode.CHUNK:
                found.setdefault(struct.unpack_from("<QQ", head, RECORD_HEAD.size), position)
            position = end
        return found

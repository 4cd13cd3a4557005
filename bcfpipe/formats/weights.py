"""The combined weight buffer of a build: every material's decoder in one ``weights.bin``.

The paper's renderer keeps all networks in one GPU buffer and finds a material's weights from its
material id (§5.3). ``bcfpipe build`` writes that buffer; the USD output points each Material at
its record (``bcf:weights``, ``bcf:weightsOffset``, ``bcf:weightsSize``, ``bcf:weightsIndex``).

Layout (version 1), little-endian, every offset in bytes from the start of the file:

  offset 0   char[4]  magic "BCFB"
  offset 4   u32      version (1)
  offset 8   u32      count N: number of records (distinct trained decoders)
  offset 12  u32      total file size in bytes
  offset 16  N table entries of 16 bytes each; entry i (the material id) is:
               u32  offset of record i (a multiple of 16)
               u32  byte size of record i (the BCFW record itself, without padding)
               u32  n_hidden of record i
               u32  n_out of record i (decoder outputs before normal z)
  then       the records, in table order, each starting on a 16-byte boundary; record i is one
             ``BCFW`` record as below; gaps are zero bytes.

One decoder's record (``BCFW``; its values' meaning: `bcfpipe.model.decoder`), little-endian:

  offset 0   char[4]  magic "BCFW"
  offset 4   u32      version: 1, or 2 with HDR channels (log_gain)
  offset 8   u32      n_in   (12)
  offset 12  u32      n_hidden
  offset 16  u32      n_out  (model channels c, before normal z)
  offset 20  u32      n_halves: count of fp16 values that follow
  offset 24  fp16     W1[n_hidden][n_in], b1[n_hidden], W2[n_out][n_hidden], b2[n_out],
                      out_scale[n_out], out_bias[n_out], and in version 2 log_gain[n_out]
             zero padding to a multiple of 4 bytes

The first record starts at ``align16(16 + 16 * N)``. Materials that share a texture set share one
record, so several Materials may name the same index and offset. Because every record starts on a
16-byte boundary and its fp16 values start 24 bytes into it, a shader reading the buffer as 32-bit
words finds value e of record i in word ``offset_i / 4 + 6 + e / 2`` (low half when e is even).
"""
from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

__all__ = ["align_up", "MAGIC", "VERSION", "ALIGN", "Entry", "pack", "unpack", "read", "write", "record",
           "RECORD_MAGIC", "RECORD_VERSIONS", "RECORD_HEADER", "RecordHeader", "record_header", "record_values",
           "record_size"]

MAGIC = b"BCFB"
VERSION = 1
ALIGN = 16
HEADER = struct.Struct("<4s3I")
ENTRY = struct.Struct("<4I")
RECORD_MAGIC = b"BCFW"
RECORD_VERSION, RECORD_VERSION_LOG = 1, 2  # 2: with log_gain[n_out] (HDR channels)
RECORD_VERSIONS = (RECORD_VERSION, RECORD_VERSION_LOG)
RECORD_HEADER = struct.Struct("<4s5I")  # magic, version, n_in, n_hidden, n_out, n_halves: 24 bytes


def record_halves(n_in: int, hidden: int, n_out: int, version: int = RECORD_VERSION) -> int:
    """How many fp16 values a record of these dimensions holds."""
    return hidden * n_in + hidden + n_out * hidden + (3 if version == RECORD_VERSION else 4) * n_out


def record_size(n_halves: int) -> int:
    """Bytes of a record with ``n_halves`` fp16 values: header, values, padding to 4 bytes."""
    return RECORD_HEADER.size + 2 * n_halves + (-2 * n_halves % 4)


@dataclass(frozen=True)
class RecordHeader:
    """A BCFW record's header, checked against its values' count and the data's length."""

    version: int
    n_in: int
    n_hidden: int
    n_out: int
    n_halves: int
    size: int  # bytes, padding included

    @property
    def dims(self) -> tuple[int, int, int]:
        return self.n_in, self.n_hidden, self.n_out


def record_header(data: bytes, offset: int = 0) -> RecordHeader:
    """The header of the record at ``offset``; ValueError if it is not a whole BCFW v1/v2 record."""
    if len(data) < offset + RECORD_HEADER.size:
        raise ValueError(f"weight record at byte {offset} is truncated")
    magic, version, n_in, hidden, n_out, n_halves = RECORD_HEADER.unpack_from(data, offset)
    if magic != RECORD_MAGIC or version not in RECORD_VERSIONS:
        raise ValueError(f"no BCFW v1/v2 weight record at byte {offset} (found {magic!r} v{version})")
    expect = record_halves(n_in, hidden, n_out, version)
    if n_halves != expect:
        raise ValueError(f"weight record at byte {offset}: {n_halves} values, expected {expect} for {n_in}-{hidden}-{n_out}")
    size = record_size(n_halves)
    if len(data) < offset + size:
        raise ValueError(f"weight record at byte {offset} is truncated")
    return RecordHeader(version, n_in, hidden, n_out, n_halves, size)


def record_values(data: bytes, offset: int = 0) -> tuple[RecordHeader, np.ndarray]:
    """The header and the fp16 values (as float32) of the record at ``offset``; ValueError if one
    is NaN or infinite."""
    head = record_header(data, offset)
    h = np.frombuffer(data, dtype="<f2", count=head.n_halves, offset=offset + RECORD_HEADER.size).astype(np.float32)
    bad = int((~np.isfinite(h)).sum())
    if bad:
        raise ValueError(f"weight record at byte {offset}: {bad} of its fp16 values are NaN or infinite")
    return head, h


def align_up(n: int) -> int:
    """``n`` bytes rounded up to the record's `ALIGN`."""
    return n + (-n % ALIGN)


@dataclass(frozen=True)
class Entry:
    """One table entry: where record ``index`` lives and its dimensions."""

    index: int
    offset: int
    size: int
    n_hidden: int
    n_out: int

    def to_dict(self) -> dict:
        return {"index": self.index, "offset": self.offset, "size_bytes": self.size,
                "n_hidden": self.n_hidden, "n_out": self.n_out}


def pack(records: Sequence[bytes]) -> tuple[bytes, list[Entry]]:
    """Combine BCFW records (``bcfpipe.model.decoder.to_bytes`` output) into one buffer; returns the bytes
    and the table entries (in record order)."""
    entries: list[Entry] = []
    pos = align_up(HEADER.size + ENTRY.size * len(records))
    for i, rec in enumerate(records):
        magic, version, _n_in, hidden, n_out, _n = RECORD_HEADER.unpack_from(rec, 0)
        if magic != RECORD_MAGIC:
            raise ValueError(f"record {i} is not a BCFW record")
        entries.append(Entry(i, pos, len(rec), hidden, n_out))
        pos = align_up(pos + len(rec))
    total = pos
    buf = bytearray(total)
    HEADER.pack_into(buf, 0, MAGIC, VERSION, len(records), total)
    for e, rec in zip(entries, records):
        ENTRY.pack_into(buf, HEADER.size + ENTRY.size * e.index, e.offset, e.size, e.n_hidden, e.n_out)
        buf[e.offset:e.offset + e.size] = rec
    return bytes(buf), entries


def unpack(data: bytes) -> list[Entry]:
    """The table of a combined buffer (validated against the records it points at)."""
    if len(data) < HEADER.size:
        raise ValueError("weight buffer is truncated")
    magic, version, count, total = HEADER.unpack_from(data, 0)
    if magic != MAGIC or version != VERSION:
        raise ValueError(f"not a BCFB v{VERSION} weight buffer (found {magic!r} v{version})")
    if total != len(data):
        raise ValueError(f"weight buffer says {total} bytes but has {len(data)}")
    entries = []
    for i in range(count):
        off, size, hidden, n_out = ENTRY.unpack_from(data, HEADER.size + ENTRY.size * i)
        if off % ALIGN:
            raise ValueError(f"record {i} at byte {off} is not {ALIGN}-byte aligned")
        rec_size = record_values(data, off)[0].size
        if rec_size != size:
            raise ValueError(f"record {i}: table says {size} bytes, record has {rec_size}")
        entries.append(Entry(i, off, size, hidden, n_out))
    return entries


def record(data: bytes, index: int) -> RecordHeader:
    """The header of record ``index`` (its values: `record_values`; as a decoder:
    bcfpipe.model.decoder.from_bytes)."""
    return record_header(data, unpack(data)[index].offset)


def write(path: str | os.PathLike, records: Sequence[bytes]) -> list[Entry]:
    data, entries = pack(records)
    Path(path).write_bytes(data)
    return entries


def read(path: str | os.PathLike) -> tuple[bytes, list[Entry]]:
    data = Path(path).read_bytes()
    return data, unpack(data)

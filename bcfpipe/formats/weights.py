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
             ``BCFW`` v1 record exactly as documented in `bcfpipe.decoder` (24-byte header, then
             fp16 W1, b1, W2, b2, out_scale, out_bias); gaps are zero bytes.

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
from typing import TYPE_CHECKING, Sequence

if TYPE_CHECKING:
    from bcfpipe.model.decoder import MlpWeights

__all__ = ["MAGIC", "VERSION", "ALIGN", "Entry", "pack", "unpack", "read", "write", "record"]

MAGIC = b"BCFB"
VERSION = 1
ALIGN = 16
HEADER = struct.Struct("<4s3I")
ENTRY = struct.Struct("<4I")
RECORD_HEADER = struct.Struct("<4s5I")  # bcfpipe.decoder.HEADER (kept here so this module imports no torch)


def _align(n: int) -> int:
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
    """Combine BCFW records (``bcfpipe.decoder.to_bytes`` output) into one buffer; returns the bytes
    and the table entries (in record order)."""
    entries: list[Entry] = []
    pos = _align(HEADER.size + ENTRY.size * len(records))
    for i, rec in enumerate(records):
        magic, version, _n_in, hidden, n_out, _n = RECORD_HEADER.unpack_from(rec, 0)
        if magic != b"BCFW":
            raise ValueError(f"record {i} is not a BCFW record")
        entries.append(Entry(i, pos, len(rec), hidden, n_out))
        pos = _align(pos + len(rec))
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
        from bcfpipe.model.decoder import from_bytes

        if off % ALIGN:
            raise ValueError(f"record {i} at byte {off} is not {ALIGN}-byte aligned")
        _, rec_size = from_bytes(data, off)
        if rec_size != size:
            raise ValueError(f"record {i}: table says {size} bytes, record has {rec_size}")
        entries.append(Entry(i, off, size, hidden, n_out))
    return entries


def record(data: bytes, index: int) -> MlpWeights:
    """The decoder weights of record ``index``."""
    from bcfpipe.model.decoder import from_bytes

    e = unpack(data)[index]
    return from_bytes(data, e.offset)[0]


def write(path: str | os.PathLike, records: Sequence[bytes]) -> list[Entry]:
    data, entries = pack(records)
    Path(path).write_bytes(data)
    return entries


def read(path: str | os.PathLike) -> tuple[bytes, list[Entry]]:
    data = Path(path).read_bytes()
    return data, unpack(data)

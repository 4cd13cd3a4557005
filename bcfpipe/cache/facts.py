"""Per-file texel facts beside the trained materials: what the plan learns by decoding a texture
(each channel's range, mean, content digest and constancy; bcfpipe.scan.content), kept under the
file's XXH3-128 so that a rebuild decodes only the textures whose bytes changed.

Layout: ``v1/facts/<h[:2]>/<xxh3_128>.json``. A fact file is written to a temporary name and
renamed into place; one that cannot be read or parsed is ignored (and recomputed), never trusted
half-written. Facts are small (a few hundred bytes per file) and derived: `bcfpipe cache clear`
removes them, and deleting them only costs a decode.
"""
from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from bcfpipe.formats.atomic import replace_atomically

FORMAT = "bcfpipe-texel-facts"
VERSION = 2  # 2: colour read as stored (unassociated alpha), not premultiplied


class FactsStore:
    def __init__(self, base: Path):
        self.dir = Path(base) / "facts"

    def _path(self, file_hash: str) -> Path:
        if not file_hash or not all(c in "0123456789abcdef" for c in file_hash):
            raise ValueError(f"bad file hash {file_hash!r}")
        return self.dir / file_hash[:2] / f"{file_hash}.json"

    def get(self, file_hash: str):
        """(channel contents, channel names) recorded for a file, or None."""
        from bcfpipe.scan.content import ChannelContent  # lazy: start-up

        try:
            d = json.loads(self._path(file_hash).read_text())
            if d.get("format") != FORMAT or d.get("version") != VERSION:
                return None
            return tuple(ChannelContent(**c) for c in d["channels"]), tuple(d["names"])
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def put(self, file_hash: str, contents, names) -> None:
        """Record a file's facts; a cache that cannot be written costs a decode next time, nothing else."""
        data = json.dumps({"format": FORMAT, "version": VERSION, "names": list(names),
                           "channels": [asdict(c) for c in contents]})
        replace_atomically(self._path(file_hash), lambda tmp: tmp.write_text(data))

    def count(self) -> int:
        return sum(1 for _ in self.dir.glob("*/*.json")) if self.dir.is_dir() else 0

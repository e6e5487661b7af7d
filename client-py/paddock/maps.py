"""Maps by content hash: find a map directory and make its bundle.

The hash is the broker's: SHA-256 over the map's files in name order, each as
(name length u64 LE, name, data length u64 LE, data). A map is named by a shipped map
name (looked up in ``PADDOCK_MAPS`` and the source tree's ``maps/``) or by a directory.
"""

from __future__ import annotations

import hashlib
import os
import struct
from dataclasses import dataclass
from pathlib import Path

from ._proto import paddock_pb2 as pb

MAX_MAP_BYTES = 48 << 20


def search_dirs() -> list[Path]:
    """Where map names are looked up: each entry of ``PADDOCK_MAPS``, then ``maps/`` of
    the source tree this package lives in."""
    dirs = [Path(p) for p in os.environ.get("PADDOCK_MAPS", "").split(":") if p]
    dirs.append(Path(__file__).resolve().parents[2] / "maps")
    return dirs


def find_map_dir(map: str) -> Path:
    """The directory of map ``map`` (a directory, a map YAML, or a shipped map name)."""
    p = Path(map)
    if p.is_dir():
        return p
    if p.is_file():
        return p.parent
    for d in search_dirs():
        if not d.is_dir():
            continue
        for entry in sorted(d.iterdir()):
            if entry.is_dir() and entry.name.lower() == map.lower():
                return entry
    searched = ", ".join(str(d) for d in search_dirs())
    raise FileNotFoundError(f"map {map!r} not found (searched: {searched})")


@dataclass(frozen=True)
class MapBundle:
    name: str
    hash: str
    files: tuple[tuple[str, bytes], ...]

    def to_proto(self) -> pb.MapBundle:
        return pb.MapBundle(
            hash=self.hash,
            name=self.name,
            files=[pb.MapFile(name=n, data=d) for n, d in self.files],
        )

    def ref(self) -> pb.MapRef:
        return pb.MapRef(name=self.name, hash=self.hash)


def bundle_hash(files: list[tuple[str, bytes]]) -> str:
    h = hashlib.sha256()
    for name, data in sorted(files, key=lambda f: f[0].encode()):
        raw = name.encode()
        h.update(struct.pack("<Q", len(raw)))
        h.update(raw)
        h.update(struct.pack("<Q", len(data)))
        h.update(data)
    return h.hexdigest()


def read_bundle(map: str) -> MapBundle:
    """Every file of the map's directory, hashed; named as the caller named it."""
    d = find_map_dir(map)
    files = []
    total = 0
    for f in sorted(d.iterdir(), key=lambda f: f.name.encode()):
        if f.is_file():
            data = f.read_bytes()
            total += len(data)
            if total > MAX_MAP_BYTES:
                raise ValueError(f"map directory {d} holds more than {MAX_MAP_BYTES} bytes")
            files.append((f.name, data))
    if not files:
        raise FileNotFoundError(f"map directory {d} holds no files")
    return MapBundle(name=map, hash=bundle_hash(files), files=tuple(files))

"""Maps by content hash: find a map directory and make its bundle.

The hash is the broker's: SHA-256 over the map's files in name order, each as
(name length u64 LE, name, data length u64 LE, data). A map is named by a directory (or
its map YAML), by the name of a folder in one of the ``PADDOCK_MAPS`` directories (both
uploaded), or by the name of a map the server ships (listed in its status, by hash, so
nothing is uploaded and nothing is looked up beside this package's files).
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
    """Where map names are looked up on this machine: each entry of ``PADDOCK_MAPS``."""
    return [Path(p) for p in os.environ.get("PADDOCK_MAPS", "").split(os.pathsep) if p]


def find_map_dir(map: str) -> Path | None:
    """The local directory of map ``map`` (a directory, a map YAML, or the name of a
    folder in a ``PADDOCK_MAPS`` directory); None when it is none of these."""
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
    return None


def server_map(map: str, shipped: list[pb.MapRef]) -> pb.MapRef:
    """The server's shipped map called ``map`` (case-insensitive), named as the caller
    named it; FileNotFoundError naming every place looked in when there is none."""
    for ref in shipped:
        if ref.name.lower() == map.lower():
            return pb.MapRef(name=map, hash=ref.hash)
    local = ", ".join(str(d) for d in search_dirs()) or "none: PADDOCK_MAPS is not set"
    names = ", ".join(sorted(r.name for r in shipped)) or "none"
    raise FileNotFoundError(
        f"map {map!r} not found: not a directory or map YAML, not in the PADDOCK_MAPS "
        f"directories ({local}), and not a map the server ships ({names})"
    )


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


def read_bundle(map: str, d: Path) -> MapBundle:
    """Every file of the map's directory ``d``, hashed; named ``map``, as the caller
    named it."""
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

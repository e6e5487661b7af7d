"""Builds the `paddock` wheel: client-py's Python package plus the `paddock` binary, as
Rust command-line tools on PyPI ship (maturin's `bindings = "bin"` layout): the binary is
the wheel's script, so pip installs it into the environment's `bin/`, where the client's
`endpoint=None` finds it; and with `--embed` the `paddock_embed` library in the package's
`_native/` folder, where `endpoint=paddock.IN_PROCESS` finds it.

The wheel is tagged `py3-none-<platform>`: any Python 3, no Python ABI, this machine's
platform (`linux_x86_64`). The binary links the C and C++ runtimes (glibc, libstdc++)
dynamically, so it runs on Linux hosts with a glibc at least as new as the build host's;
a manylinux tag for PyPI would need that checked (auditwheel). It is reproducible:
entries sorted, fixed timestamps (SOURCE_DATE_EPOCH when set). Standard library only.

    python3 scripts/build_wheel.py --binary target/release/paddock --out dist
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import os
import stat
import sysconfig
import time
import zipfile
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    raise SystemExit("build_wheel.py needs Python 3.11 or newer (tomllib)")

ROOT = Path(__file__).resolve().parents[1]
CLIENT = ROOT / "client-py"


def record_hash(data: bytes) -> str:
    digest = hashlib.sha256(data).digest()
    return "sha256=" + base64.urlsafe_b64encode(digest).rstrip(b"=").decode()


def metadata(project: dict) -> str:
    lines = [
        "Metadata-Version: 2.1",
        f"Name: {project['name']}",
        f"Version: {project['version']}",
        f"Summary: {project['description']}",
        f"License: {project['license']}",
        f"Requires-Python: {project['requires-python']}",
    ]
    lines += [f"Requires-Dist: {d}" for d in project.get("dependencies", [])]
    for extra, deps in sorted(project.get("optional-dependencies", {}).items()):
        lines.append(f"Provides-Extra: {extra}")
        lines += [f'Requires-Dist: {d}; extra == "{extra}"' for d in deps]
    readme = (CLIENT / "README.md").read_text()
    lines.append("Description-Content-Type: text/markdown")
    return "\n".join(lines) + "\n\n" + readme


def platform_tag() -> str:
    return sysconfig.get_platform().replace("-", "_").replace(".", "_")


def build(binary: Path, out: Path, embed: Path | None = None) -> Path:
    project = tomllib.loads((CLIENT / "pyproject.toml").read_text())["project"]
    name, version = project["name"], project["version"]
    tag = f"py3-none-{platform_tag()}"
    dist_info = f"{name}-{version}.dist-info"
    entries: list[tuple[str, bytes, int]] = []
    for f in sorted((CLIENT / "paddock").rglob("*")):
        if f.is_file() and "__pycache__" not in f.parts and f.suffix in (".py", ".pyi", ".typed"):
            entries.append((f.relative_to(CLIENT).as_posix(), f.read_bytes(), 0o644))
    entries.append((f"{name}-{version}.data/scripts/paddock", binary.read_bytes(), 0o755))
    if embed is not None:
        # the in-process simulator (paddock.inprocess), loaded with ctypes: no Python ABI
        entries.append((f"paddock/_native/{embed.name}", embed.read_bytes(), 0o755))
    entries.append((f"{dist_info}/METADATA", metadata(project).encode(), 0o644))
    wheel = f"Wheel-Version: 1.0\nGenerator: paddock build_wheel.py\nRoot-Is-Purelib: false\nTag: {tag}\n"
    entries.append((f"{dist_info}/WHEEL", wheel.encode(), 0o644))
    record = "".join(f"{p},{record_hash(d)},{len(d)}\n" for p, d, _ in entries)
    record += f"{dist_info}/RECORD,,\n"
    entries.append((f"{dist_info}/RECORD", record.encode(), 0o644))

    epoch = int(os.environ.get("SOURCE_DATE_EPOCH", "315532800"))  # 1980-01-01
    stamp = time.gmtime(max(epoch, 315532800))[:6]
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}-{version}-{tag}.whl"
    tmp = path.with_suffix(".tmp")
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for p, data, mode in entries:
            info = zipfile.ZipInfo(p, date_time=stamp)
            info.external_attr = (stat.S_IFREG | mode) << 16
            info.compress_type = zipfile.ZIP_DEFLATED
            z.writestr(info, data)
    tmp.replace(path)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--binary", type=Path, required=True, help="the paddock binary to ship")
    ap.add_argument("--embed", type=Path, default=None,
                    help="the paddock_embed library to ship (libpaddock_embed.so)")
    ap.add_argument("--out", type=Path, default=ROOT / "dist", help="output folder")
    args = ap.parse_args()
    if not (args.binary.is_file() and os.access(args.binary, os.X_OK)):
        raise SystemExit(f"--binary {args.binary}: not an executable file")
    if args.embed is not None and not args.embed.is_file():
        raise SystemExit(f"--embed {args.embed}: not a file")
    print(build(args.binary, args.out, args.embed))


if __name__ == "__main__":
    main()

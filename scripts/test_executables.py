"""The test executables of some workspace packages, from `cargo test --no-run
--message-format=json` (or `json-render-diagnostics`) on stdin: one line per executable, its package's folder and its
path separated by a tab, in cargo's build order. Used by scripts/test.sh.

    cargo test --workspace --release --no-run --message-format=json |
        python3 scripts/test_executables.py PACKAGE...
"""

import json
import os
import signal
import sys

# quiet on a closed pipe, as a Unix tool
signal.signal(signal.SIGPIPE, signal.SIG_DFL)


def main() -> int:
    wanted = set(sys.argv[1:])
    if not wanted:
        print("usage: test_executables.py PACKAGE...", file=sys.stderr)
        return 2
    found = set()
    for line in sys.stdin:
        if not line.startswith("{"):
            continue
        msg = json.loads(line)
        if msg.get("reason") != "compiler-artifact" or not msg.get("executable"):
            continue
        if not msg.get("profile", {}).get("test"):
            continue
        # package_id: "path+file:///…/folder#name@version" (or "…#version" when the
        # folder is named after the package)
        pid = msg["package_id"]
        spec = pid.rsplit("#", 1)[-1]
        name = spec.rsplit("@", 1)[0] if "@" in spec else pid.split("#")[0].rstrip("/").rsplit("/", 1)[-1]
        if name in wanted:
            found.add(name)
            print(f"{os.path.dirname(msg['manifest_path'])}\t{msg['executable']}")
    missing = wanted - found
    if missing:
        print(f"error: no test executables for package(s) {', '.join(sorted(missing))}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

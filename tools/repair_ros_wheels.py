"""Repair the CMake exports of the ROS 2 wheels installed in this venv.

The ros-jazzy-* wheels were built in a manylinux image and their CMake files
hard-code that image's Python include directory, numpy include directory and
prefix (/opt/python/cp311-cp311). colcon builds of rosidl packages need them
to point at this venv. Idempotent: files already repaired are left alone.
"""

from __future__ import annotations

import sys
import sysconfig
from pathlib import Path

BUILD_PREFIX = "/opt/python/cp311-cp311"


def replacements(prefix: Path) -> list[tuple[bytes, bytes]]:
    """Byte replacements that point the wheels' CMake files at this venv's paths."""
    import numpy

    include = sysconfig.get_paths()["include"]
    # Longest first so the specific paths win over the bare prefix.
    return [
        (f"{BUILD_PREFIX}/lib/python3.11/site-packages/numpy/_core/include".encode(),
         numpy.get_include().encode()),
        (f"{BUILD_PREFIX}/include/python3.11".encode(), include.encode()),
        (BUILD_PREFIX.encode(), str(prefix).encode()),
    ]


def repair(prefix: Path) -> int:
    """Apply the replacements under the prefix; returns the number of files changed."""
    pairs = replacements(prefix)
    changed = 0
    roots = [prefix / "share", prefix / "lib" / "cmake"]
    for root in roots:
        if not root.is_dir():
            continue
        for path in root.rglob("*"):
            if not path.is_file() or path.is_symlink() or path.stat().st_size > 4 << 20:
                continue
            data = path.read_bytes()
            if BUILD_PREFIX.encode() not in data:
                continue
            for old, new in pairs:
                data = data.replace(old, new)
            path.write_bytes(data)
            changed += 1
    return changed


def main() -> int:
    """Repair the venv's ROS wheels; exit code."""
    prefix = Path(sys.prefix)
    if not (prefix / "share" / "ament_cmake").is_dir():
        print(f"repair_ros_wheels: {prefix} has no ament_cmake; install the ros-jazzy wheels first",
              file=sys.stderr)
        return 1
    changed = repair(prefix)
    print(f"repair_ros_wheels: rewrote {changed} file(s) under {prefix}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""CI, the aarch64 job (issue 52, item 5): the runtime's dependencies resolve as Linux aarch64 wheels.

Each runtime dependency of pyproject.toml ([project] dependencies, at its version spec) is fetched as a binary
wheel for Linux aarch64 and CPython 3.11, without its own dependencies:

    python -m pip download --platform manylinux2014_aarch64 --only-binary=:all: --python-version 3.11 \\
        --no-deps -d TMPDIR "SPEC"

A dependency with no manylinux2014 (glibc 2.17) wheel in its range is tried again as manylinux_2_28 (glibc 2.28)
and reported as such: every board the runtime targets has a newer glibc (Raspberry Pi OS Bookworm 2.36,
Ubuntu 22.04 of JetPack 6 2.35, Ubuntu 20.04 of JetPack 5 2.31). One line per dependency says which wheel
resolved; the exit status is 1, with pip's reason, when one resolves as neither.

    python .ci/aarch64_wheels.py [--python-version 3.11]
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PLATFORMS = ("manylinux2014_aarch64", "manylinux_2_28_aarch64")  # tried in this order


def runtime_dependencies(pyproject: Path = ROOT / "pyproject.toml") -> list[str]:
    try:
        import tomllib
    except ImportError:  # Python 3.10: pip's own copy of tomli reads it the same way
        from pip._vendor import tomli as tomllib
    return list(tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]["dependencies"])


def fetch(spec: str, platform: str, python_version: str, dest: Path) -> tuple[str | None, str]:
    """(the wheel's file name or None, pip's last lines when it failed)."""
    dest.mkdir(parents=True)
    cmd = [sys.executable, "-m", "pip", "download", "--platform", platform, "--only-binary=:all:",
           "--python-version", python_version, "--no-deps", "--retries", "2", "--timeout", "20",
           "--disable-pip-version-check", "-q", "-d", str(dest), spec]
    out = subprocess.run(cmd, capture_output=True, text=True)
    wheels = sorted(p.name for p in dest.glob("*.whl"))
    if out.returncode == 0 and wheels:
        return wheels[0], ""
    tail = [ln for ln in (out.stderr + out.stdout).strip().splitlines() if ln.strip()][-3:]
    return None, " | ".join(tail)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--python-version", default="3.11")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    deps = runtime_dependencies()
    failed, newer = [], []
    with tempfile.TemporaryDirectory(prefix="aarch64-wheels-") as tmp:
        for i, spec in enumerate(deps):
            why = []
            for platform in PLATFORMS:
                t = time.perf_counter()
                wheel, reason = fetch(spec, platform, args.python_version, Path(tmp) / f"{i}-{platform}")
                if wheel:
                    note = "" if platform == PLATFORMS[0] else f" (none as {PLATFORMS[0]}: needs glibc ≥ 2.28)"
                    print(f"{spec}: {platform}: {wheel}{note}, {time.perf_counter() - t:.1f} s", flush=True)
                    if platform != PLATFORMS[0]:
                        newer.append(spec)
                    break
                why.append(f"{platform}: {reason}")
            else:
                failed.append(spec)
                print(f"{spec}: NO aarch64 wheel for CPython {args.python_version}: " + "; ".join(why), flush=True)
    took = time.perf_counter() - t0
    summary = (f"aarch64, CPython {args.python_version}: {len(deps) - len(failed)} of {len(deps)} runtime "
               f"dependencies resolve as binary wheels")
    if newer:
        summary += f"; only as manylinux_2_28 (glibc ≥ 2.28): {', '.join(newer)}"
    print(f"{summary}; {took:.1f} s")
    if failed:
        print(f"aarch64 check failed: {', '.join(failed)} cannot be installed from wheels on Linux aarch64 "
              "(a Raspberry Pi 5 or a Jetson would build it from source, or not at all)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

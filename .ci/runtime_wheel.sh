#!/usr/bin/env bash
# The runtime-wheel job of .ci/run (issue 52, item 3): the two distributions built as wheels, their sizes,
# then `pip install radar-odom` (the runtime wheel, its dependencies from the index) in a fresh venv with no
# torch, and README.md's API block run as a new user would: in a folder where `radar-odom simulate seq
# --frames 6` was run. Also: torch and the torch side are not importable there, and `radar-odom train`
# says how to install the torch side. Usage: bash .ci/runtime_wheel.sh PYTHON_WITH_SETUPTOOLS_77
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_PY="$1"
WORK="$(mktemp -d)"
trap 'rm -rf "$WORK"' EXIT
"$BUILD_PY" -m pip wheel -q --no-deps --no-build-isolation -w "$WORK/dist" . ./export
echo "wheels (bytes, file):"
(cd "$WORK/dist" && stat -c '%s %n' ./*.whl)
python3 -m venv "$WORK/venv"
# shellcheck disable=SC1091
. "$WORK/venv/bin/activate"
python -m pip install -q "$WORK"/dist/radar_odom-*.whl
python - <<'PY'
import importlib.util

for name in ("torch", "radar_odom_export"):
    assert importlib.util.find_spec(name) is None, f"{name} is importable after pip install radar-odom"
print("pip install radar-odom: no torch, no radar_odom_export")
PY
rc=0
radar-odom train -o x.pt 2>"$WORK/train.err" || rc=$?
cat "$WORK/train.err"
[ "$rc" -eq 1 ] && grep -q "pip install radar-odom-export" "$WORK/train.err"
ROOT="$PWD"
mkdir "$WORK/user" && cd "$WORK/user"
radar-odom simulate seq --frames 6 >/dev/null
python - "$ROOT/README.md" <<'PY'
import re
import sys

text = open(sys.argv[1]).read()
section = text[text.index("## The API in a few lines"):]
section = section[: section.index("\n## ", 1)]
(block,) = re.findall(r"```python\n(.*?)```", section, re.S)
exec(compile(block, "README.md, The API in a few lines", "exec"), {"__name__": "__readme__"})
print("README.md's API block ran on the installed runtime wheel")
PY
deactivate

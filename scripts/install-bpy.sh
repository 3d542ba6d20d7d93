#!/usr/bin/env bash
# Blender as a Python module (PyPI bpy, pinned in scripts/blender/requirements.txt) in a venv at
# target/bpy-venv, where tests/export.rs and scripts/blender/import_check.py's callers look for it
# (override: BPY_PYTHON=the venv's python). bpy 4.5 ships wheels for CPython 3.11 only (x86_64
# Linux: about 350 MB to download, 1 GB installed); python3 must be 3.11 with venv support.
set -euo pipefail
cd "$(dirname "$0")/.."
DIR=target/bpy-venv
WANT=$(sed -n 's/^bpy==//p' scripts/blender/requirements.txt)
if [ -x "$DIR/bin/python" ] && [ "$("$DIR/bin/python" -c 'import importlib.metadata as m; print(m.version("bpy"))' 2>/dev/null)" = "$WANT" ]; then
  echo "bpy $WANT already in $DIR"
  exit 0
fi
PY=$(python3 -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')
if [ "$PY" != "3.11" ]; then
  echo "install-bpy.sh: bpy $WANT needs CPython 3.11, python3 is $PY" >&2
  exit 1
fi
rm -rf "$DIR"
python3 -m venv "$DIR"
"$DIR/bin/pip" install --quiet --disable-pip-version-check -r scripts/blender/requirements.txt
echo "bpy $WANT installed in $DIR"

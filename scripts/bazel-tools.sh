#!/usr/bin/env bash
# Sourced by scripts/bazel-remote.sh and scripts/bazel-remote-exec.sh (with REPO, TOOLS and BAKE
# set): makes TOOLS and BAKE absolute, builds bake if it is missing, and installs what both need
# under TOOLS: npm's @bazel/bazel 2.1.0 (BAZEL) and BuildGrid 0.4.4 in a virtual environment
# (BGD, PY), with psycopg2 for the PostgreSQL scheduler. Reinstalls nothing that is there.
# Run directly (`scripts/bazel-tools.sh`), it only installs the tools into target/bazel-tools
# (.ci/run does that while the compiler works).
if [ "${BASH_SOURCE[0]}" = "$0" ]; then
  set -euo pipefail
  REPO=$(cd "$(dirname "$0")/.." && pwd)
  TOOLS=${BAKE_TOOLS:-$REPO/target/bazel-tools}
  TOOLS_ONLY=1
fi
mkdir -p "$TOOLS"
TOOLS=$(cd "$TOOLS" && pwd)

if [ -z "${TOOLS_ONLY:-}" ]; then
  if [ ! -x "$BAKE" ]; then (cd "$REPO" && cargo build --quiet); fi
  BAKE=$(cd "$(dirname "$BAKE")" && pwd)/$(basename "$BAKE")
fi

echo "== tools in $TOOLS"
BAZEL=$TOOLS/node_modules/@bazel/bazel-linux_x64/bazel-2.1.0-linux-x86_64
if [ ! -x "$BAZEL" ]; then
  command -v npm >/dev/null || { echo "npm is needed (apt-get install npm)"; exit 1; }
  npm install --silent --no-audit --no-fund --prefix "$TOOLS" @bazel/bazel@2.1.0 >/dev/null
fi
# npm leaves the platform binary without its executable bit here (mode 0644); the scripts call
# the binary directly, not through the package's launcher, so the bit is set here.
[ -x "$BAZEL" ] || chmod +x "$BAZEL"
BGD=$TOOLS/venv/bin/bgd
PY=$TOOLS/venv/bin/python
if [ ! -x "$BGD" ]; then
  python3 -m venv "$TOOLS/venv"
  "$TOOLS/venv/bin/pip" install --quiet buildgrid==0.4.4   # the version the scripts were written against
fi
# BuildGrid's scheduler talks to PostgreSQL through psycopg2 (scripts/bazel-remote-exec.sh; its
# LISTEN/NOTIFY code imports it).
if ! "$PY" -c 'import psycopg2' 2>/dev/null; then
  "$TOOLS/venv/bin/pip" install --quiet psycopg2-binary==2.9.13
fi

# Sourced by scripts/bazel-remote.sh and scripts/bazel-remote-exec.sh (with REPO, TOOLS and BAKE
# set): makes TOOLS and BAKE absolute, builds bake if it is missing, and installs what both need
# under TOOLS: npm's @bazel/bazel 2.1.0 (BAZEL) and BuildGrid 0.4.4 in a virtual environment
# (BGD, PY). Reinstalls nothing that is there.
mkdir -p "$TOOLS"
TOOLS=$(cd "$TOOLS" && pwd)

if [ ! -x "$BAKE" ]; then (cd "$REPO" && cargo build --quiet); fi
BAKE=$(cd "$(dirname "$BAKE")" && pwd)/$(basename "$BAKE")

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

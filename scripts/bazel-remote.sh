#!/usr/bin/env bash
# Issue 17, item 4: the fixture's plan built by Bazel against a real Remote Execution API server
# on 127.0.0.1 (BuildGrid from PyPI: CAS, ByteStream, ActionCache).
#
#   1. `bake plan fixtures/scene --emit bazel` into a fresh workspace;
#   2. `bazel build //:scene --remote_cache=grpc://127.0.0.1:PORT` (every action runs, uploads);
#   3. `bazel clean`, build again: every bake action must be a remote cache hit (the execution
#      log's `remoteCacheHit` and Bazel's process summary), the pack's bytes unchanged and equal
#      to the single-process `bake SCENE.eco` with the same arguments.
#
# Installs what it needs (npm's @bazel/bazel 2.1.0, BuildGrid in a virtual environment) under
# $BAKE_TOOLS (default target/bazel-tools). BAKE= the bake binary (default target/debug/bake,
# built if missing). Exits non-zero on any failure; prints PASS at the end.
set -euo pipefail
cd "$(dirname "$0")/.."
REPO=$PWD
TOOLS=${BAKE_TOOLS:-$REPO/target/bazel-tools}
BAKE=${BAKE:-$REPO/target/debug/bake}
PORT=${BAKE_REAPI_PORT:-50077}
# shellcheck source=scripts/bazel-tools.sh
. "$REPO/scripts/bazel-tools.sh"
"$BAZEL" --version 2>/dev/null | head -1 || true

WORK=$(mktemp -d)
SERVER_PID=""
cleanup() {
  [ -n "$SERVER_PID" ] && kill "$SERVER_PID" 2>/dev/null || true
  if [ -d "$WORK/ws" ]; then
    (cd "$WORK/ws" && "$BAZEL" --output_user_root="$WORK/root" shutdown >/dev/null 2>&1) || true
  fi
  chmod -R u+w "$WORK" 2>/dev/null || true
  rm -rf "$WORK"
}
trap cleanup EXIT

echo "== BuildGrid on 127.0.0.1:$PORT"
cat > "$WORK/bgd.yml" <<YML
server:
  - !channel
    address: "127.0.0.1:$PORT"
    insecure-mode: true
authorization:
  method: none
storages:
  - !disk-storage &cas
    path: $WORK/cas
caches:
  - !lru-action-cache &ac
    storage: *cas
    max-cached-refs: 10000
    allow-updates: true
    cache-failed-actions: false
instances:
  - name: ""
    services:
      - !action-cache
        cache: *ac
      - !cas
        storage: *cas
      - !bytestream
        storage: *cas
YML
"$BGD" server start "$WORK/bgd.yml" > "$WORK/bgd.log" 2>&1 &
SERVER_PID=$!
for _ in $(seq 1 100); do
  if (exec 3<>/dev/tcp/127.0.0.1/"$PORT") 2>/dev/null; then break; fi
  kill -0 "$SERVER_PID" 2>/dev/null || { cat "$WORK/bgd.log"; echo "BuildGrid did not start"; exit 1; }
  sleep 0.2
done

echo "== the plan"
"$BAKE" -q fixtures "$WORK/fx"
"$BAKE" plan "$WORK/fx/scene.eco" --sky "$WORK/fx/sky.hdr" --pipeline ci \
  --emit bazel -o "$WORK/ws"
ACTIONS=$(grep -c '^bake_unit(' "$WORK/ws/BUILD.bazel")
echo "$ACTIONS actions"

cd "$WORK/ws"
# Local spawns run in the execroot, not in Bazel's linux-sandbox: the sandbox links every input
# file separately to its place outside the sandbox, and bake's scene confinement (which resolves
# links) refuses a model or RAW file outside the scene's folder. Hermeticity is checked by
# tests/ninja.rs (each action alone in a folder of copies).
FLAGS=(--remote_cache=grpc://127.0.0.1:$PORT --noshow_progress --spawn_strategy=local)
bz() { "$BAZEL" --output_user_root="$WORK/root" "$@"; }

echo "== first build: every action runs, results uploaded"
bz build //:scene "${FLAGS[@]}" --execution_log_json_file="$WORK/first.json" > "$WORK/first.log" 2>&1 \
  || { cat "$WORK/first.log"; exit 1; }
grep -E "processes" "$WORK/first.log"
cp bazel-bin/scene.bake "$WORK/first.bake"

echo "== bazel clean, second build: every action a remote cache hit"
bz clean
bz build //:scene "${FLAGS[@]}" --execution_log_json_file="$WORK/second.json" > "$WORK/second.log" 2>&1 \
  || { cat "$WORK/second.log"; exit 1; }
grep -E "processes" "$WORK/second.log"
grep -q "$ACTIONS remote cache hit" "$WORK/second.log" || { echo "not every one of $ACTIONS actions was a remote cache hit"; cat "$WORK/second.log"; exit 1; }
python3 - "$WORK/second.json" "$ACTIONS" <<'PY'
import json, sys
text = open(sys.argv[1]).read()
dec = json.JSONDecoder(); i = 0; spawns = []
while i < len(text):
    while i < len(text) and text[i].isspace(): i += 1
    if i >= len(text): break
    obj, i = dec.raw_decode(text, i); spawns.append(obj)
bake = [s for s in spawns if s.get("mnemonic") == "Genrule"]
miss = [s.get("progressMessage") for s in bake if not s.get("remoteCacheHit")]
print(f"{len(bake)} bake spawns in the execution log, {len(bake) - len(miss)} remote cache hits")
assert len(bake) == int(sys.argv[2]), (len(bake), sys.argv[2])
assert not miss, miss
PY
cmp "$WORK/first.bake" bazel-bin/scene.bake
echo "pack unchanged after the cache round trip ($(stat -c %s bazel-bin/scene.bake) bytes)"

echo "== against the single-process bake"
"$BAKE" -q src/scene.eco --sky src/sky.hdr --pipeline ci --no-cache -o "$WORK/reference.bake"
cmp "$WORK/reference.bake" bazel-bin/scene.bake
echo "PASS: Bazel 2.1.0 + BuildGrid remote cache: $ACTIONS/$ACTIONS remote cache hits, pack identical to bake SCENE.eco"

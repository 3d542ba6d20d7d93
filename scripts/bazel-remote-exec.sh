#!/usr/bin/env bash
# Issue 17, item 4, second half: the fixture's plan built by Bazel with remote *execution*
# through a real Remote Execution API server on 127.0.0.1 (docs/SCALING.md, "Remote execution").
#
#   1. PostgreSQL in a fresh data folder, listening on a unix socket only (no TCP), run as a
#      non-root user (as root: `postgres` if the machine has that user, else a system user this
#      script creates), for BuildGrid's SQL scheduler (BuildGrid 0.4.4 refuses SQLite);
#   2. BuildGrid on 127.0.0.1:PORT (a free port) with the Execution, Operations, Bots, CAS,
#      ByteStream and ActionCache services of one instance (the empty name), scheduler on that
#      PostgreSQL;
#   3. scripts/reapi-bot.py, our Remote Workers API bot, with --workers 2 sessions;
#   4. `bake plan fixtures/scene --emit bazel` into a fresh workspace and
#      `bazel build //:scene --remote_executor=grpc://127.0.0.1:PORT` with
#      --spawn_strategy=remote --genrule_strategy=remote --remote_local_fallback=false;
#   5. checks: Bazel's summary `N processes: N remote.`, every Genrule spawn of
#      --execution_log_json_file with runner "remote" and not a remote cache hit, the bot's log
#      with exactly N completed leases (exit code 0, status OK), and the pack equal (cmp) to the
#      single-process `bake SCENE.eco` with the same arguments;
#   6. `bazel clean` and a second build against the same server: every action is now a remote
#      cache hit (the results the bot reported, stored by BuildGrid in its action cache), the
#      pack unchanged;
#   7. for comparison, `bazel clean` and the same build with local spawns (no server): its wall
#      time is printed beside the remote one, and its pack is the same.
#
# A script of its own (not a phase of scripts/bazel-remote.sh): .ci/run gives it its own
# `timeout`, it needs PostgreSQL and a bot that the cache test does not, and a failure here
# names remote execution rather than the cache round trip.
#
# Installs what it needs under $BAKE_TOOLS (default target/bazel-tools): npm's @bazel/bazel
# 2.1.0, BuildGrid 0.4.4 and psycopg2-binary in a virtual environment. PostgreSQL's server
# binaries come from Debian's `postgresql` package (.ci/run installs it; BAKE_PG_BIN= a folder
# holding initdb and pg_ctl overrides the search). BAKE= the bake binary (default
# target/debug/bake, built if missing). All traffic is on 127.0.0.1 and one unix socket. Every
# wait is bounded; servers are stopped on exit. Exits non-zero on any failure; prints PASS.
set -euo pipefail
cd "$(dirname "$0")/.."
REPO=$PWD
TOOLS=${BAKE_TOOLS:-$REPO/target/bazel-tools}
BAKE=${BAKE:-$REPO/target/debug/bake}
WORKERS=${BAKE_BOT_WORKERS:-2}
T0=$(date +%s)
# shellcheck source=scripts/bazel-tools.sh
. "$REPO/scripts/bazel-tools.sh"

PG_BIN=${BAKE_PG_BIN:-}
if [ -z "$PG_BIN" ]; then
  for d in $(ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V -r) "$(dirname "$(command -v initdb 2>/dev/null || echo /nonexistent/x)")"; do
    if [ -x "$d/initdb" ] && [ -x "$d/pg_ctl" ]; then PG_BIN=$d; break; fi
  done
fi
[ -n "$PG_BIN" ] || { echo "PostgreSQL's server binaries are needed (apt-get install postgresql)"; exit 1; }
echo "PostgreSQL: $("$PG_BIN/postgres" --version)"

WORK=$(mktemp -d)
# PostgreSQL's folder: its own, so that the server's user can reach it (mktemp -d is 0700).
PGDIR=$(mktemp -d /tmp/bake-pg.XXXXXX)
SERVER_PID=""
BOT_PID=""
PG_STARTED=""
if [ "$(id -u)" = 0 ]; then
  # postgres refuses to run as root.
  # BAKE_PG_USER= another user (created if missing).
  PG_USER=${BAKE_PG_USER:-}
  if [ -z "$PG_USER" ]; then
    if id -u postgres >/dev/null 2>&1; then PG_USER=postgres; else PG_USER=bake-pg; fi
  fi
  id -u "$PG_USER" >/dev/null 2>&1 \
    || useradd --system --no-create-home --home-dir /nonexistent --shell /usr/sbin/nologin "$PG_USER"
  chown "$PG_USER" "$PGDIR"
  as_pg() { runuser -u "$PG_USER" -- "$@"; }
else
  PG_USER=$(id -un)
  as_pg() { "$@"; }
fi

cleanup() {
  local rc=$?
  set +e
  if [ -n "$BOT_PID" ] && kill -0 "$BOT_PID" 2>/dev/null; then
    kill -TERM "$BOT_PID" 2>/dev/null
    for _ in $(seq 1 50); do kill -0 "$BOT_PID" 2>/dev/null || break; sleep 0.2; done
    kill -KILL "$BOT_PID" 2>/dev/null
  fi
  if [ -d "$WORK/ws" ]; then
    (cd "$WORK/ws" && timeout 60 "$BAZEL" --output_user_root="$WORK/root" --max_idle_secs=300 shutdown >/dev/null 2>&1)
  fi
  if [ -n "$SERVER_PID" ] && kill -0 "$SERVER_PID" 2>/dev/null; then
    kill -TERM "$SERVER_PID" 2>/dev/null
    for _ in $(seq 1 50); do kill -0 "$SERVER_PID" 2>/dev/null || break; sleep 0.2; done
    kill -KILL "$SERVER_PID" 2>/dev/null
  fi
  if [ -n "$PG_STARTED" ]; then
    as_pg "$PG_BIN/pg_ctl" -D "$PGDIR/data" -m immediate -t 30 -w stop >/dev/null 2>&1
  fi
  if [ "$rc" != 0 ]; then
    for f in "$WORK/bgd.log" "$WORK/bot.out" "$PGDIR/postgres.log"; do
      [ -s "$f" ] && { echo "--- last lines of $f"; tail -40 "$f"; }
    done
  fi
  chmod -R u+w "$WORK" 2>/dev/null
  rm -rf "$WORK" "$PGDIR"
  exit "$rc"
}
trap cleanup EXIT
trap 'exit 143' TERM INT

echo "== PostgreSQL ($PG_USER) in $PGDIR, unix socket only"
as_pg "$PG_BIN/initdb" -D "$PGDIR/data" -A trust -U bgd -E UTF8 --no-sync > "$PGDIR/initdb.log" 2>&1 \
  || { cat "$PGDIR/initdb.log"; exit 1; }
PG_STARTED=1
as_pg "$PG_BIN/pg_ctl" -D "$PGDIR/data" -l "$PGDIR/postgres.log" -w -t 60 \
  -o "-c listen_addresses='' -k $PGDIR -c fsync=off -c synchronous_commit=off -c full_page_writes=off" start >/dev/null
as_pg "$PG_BIN/createdb" -h "$PGDIR" -U bgd bgd
DB="postgresql+psycopg2://bgd@/bgd?host=$PGDIR"
(cd "$WORK" && timeout 120 "$BGD" migrate apply "$DB" > "$WORK/migrate.log" 2>&1) \
  || { cat "$WORK/migrate.log"; exit 1; }

PORT=${BAKE_REAPI_EXEC_PORT:-$("$PY" -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')}
echo "== BuildGrid on 127.0.0.1:$PORT (execution, bots, CAS, ByteStream, action cache)"
cat > "$WORK/bgd.yml" <<YML
server:
  - !channel
    address: "127.0.0.1:$PORT"
    insecure-mode: true
authorization:
  method: none
# gRPC worker threads, which bound BuildGrid's concurrent RPCs (default 5 per core, 10 here:
# Bazel's open Execute streams and the bot sessions' long polls exceed that).
thread-pool-size: 64
storages:
  - !disk-storage &cas
    path: $WORK/cas
caches:
  - !lru-action-cache &ac
    storage: *cas
    max-cached-refs: 10000
    allow-updates: true
    cache-failed-actions: false
connections:
  - !sql-connection &sql
    connection-string: "$DB"
    pool-size: 5
    max-overflow: 10
schedulers:
  - !sql-scheduler &scheduler
    storage: *cas
    sql: *sql
    action-cache: *ac
    # Short polls: each action's latency (queued -> assigned -> bot woken -> completed -> Bazel
    # told) is a few of these intervals, and the plan is a chain of short actions.
    poll-interval: 0.1
    bot-poll-interval: 0.1
    assigners:
      - !priority-age-assigner
        count: 1
        interval: 0.1
    max-execution-timeout: 600
    max-job-attempts: 2
    bot-session-keepalive-timeout: 60
instances:
  - name: ""
    services:
      - !action-cache
        cache: *ac
      - !execution
        scheduler: *scheduler
      - !bots
        scheduler: *scheduler
      - !cas
        storage: *cas
      - !bytestream
        storage: *cas
YML
(cd "$WORK" && exec "$BGD" server start "$WORK/bgd.yml") > "$WORK/bgd.log" 2>&1 &
SERVER_PID=$!
for i in $(seq 1 150); do
  if (exec 3<>/dev/tcp/127.0.0.1/"$PORT") 2>/dev/null; then break; fi
  kill -0 "$SERVER_PID" 2>/dev/null || { echo "BuildGrid did not start"; exit 1; }
  [ "$i" = 150 ] && { echo "BuildGrid not listening after 30 s"; exit 1; }
  sleep 0.2
done

echo "== the bot: $WORKERS sessions"
"$PY" "$REPO/scripts/reapi-bot.py" --server "127.0.0.1:$PORT" --workers "$WORKERS" \
  --work "$WORK/bot" --log "$WORK/bot.jsonl" --deadline 420 --action-timeout 300 \
  > "$WORK/bot.out" 2>&1 &
BOT_PID=$!

echo "== the plan"
"$BAKE" -q fixtures "$WORK/fx"
"$BAKE" plan "$WORK/fx/scene.eco" --sky "$WORK/fx/sky.hdr" --pipeline ci \
  --emit bazel -o "$WORK/ws"
ACTIONS=$(grep -c '^bake_unit(' "$WORK/ws/BUILD.bazel")

cd "$WORK/ws"
# --max_idle_secs: a Bazel server left behind by a killed run ends by itself.
bz() { timeout 240 "$BAZEL" --output_user_root="$WORK/root" --max_idle_secs=300 "$@"; }
# A build that needs the bot fails at once if the bot stops (it exits on an error it cannot
# retry) instead of waiting for its leases until the timeout.
bz_build() {
  local log=$1; shift
  : > "$log"
  kill -0 "$BOT_PID" 2>/dev/null || { cat "$WORK/bot.out"; echo "FAIL: the bot is not running"; exit 1; }
  timeout 240 "$BAZEL" --output_user_root="$WORK/root" --max_idle_secs=300 build "$@" > "$log" 2>&1 &
  local pid=$!
  while sleep 0.5; kill -0 "$pid" 2>/dev/null; do
    if ! kill -0 "$BOT_PID" 2>/dev/null; then
      kill -TERM "$pid" 2>/dev/null
      wait "$pid" 2>/dev/null || true
      cat "$log"; echo "FAIL: the bot stopped during the build"; exit 1
    fi
  done
  wait "$pid" || { cat "$log"; echo "FAIL: bazel build"; exit 1; }
}
# Nothing may run on this machine outside the bot: every spawn remote, no local fallback.
FLAGS=(--remote_executor=grpc://127.0.0.1:$PORT --spawn_strategy=remote --genrule_strategy=remote
  --remote_local_fallback=false --remote_timeout=300 --jobs=8 --noshow_progress)
bz version >/dev/null 2>&1   # Bazel's server started before the timed build

echo "== remote execution: $ACTIONS actions through BuildGrid and the bot"
S=$(date +%s%N)
bz_build "$WORK/exec.log" //:scene "${FLAGS[@]}" --execution_log_json_file="$WORK/exec.json"
E=$(date +%s%N)
grep -E "processes|Elapsed" "$WORK/exec.log"
grep -q "^INFO: $ACTIONS processes: $ACTIONS remote\.$" "$WORK/exec.log" \
  || { echo "not every one of $ACTIONS actions ran remotely"; cat "$WORK/exec.log"; exit 1; }
check_log() {  # exec.json, expected actions, what the spawns must be: executed | cached
  "$PY" - "$@" <<'PY'
import json, sys
text = open(sys.argv[1]).read()
dec = json.JSONDecoder(); i = 0; spawns = []
while i < len(text):
    while i < len(text) and text[i].isspace(): i += 1
    if i >= len(text): break
    obj, i = dec.raw_decode(text, i); spawns.append(obj)
bake = [s for s in spawns if s.get("mnemonic") == "Genrule"]
assert len(bake) == int(sys.argv[2]), f"{len(bake)} Genrule spawns, expected {sys.argv[2]}"
assert len(spawns) == len(bake), [s.get("mnemonic") for s in spawns if s.get("mnemonic") != "Genrule"]
bad = [s.get("progressMessage") for s in bake if s.get("exitCode", 0) != 0]
assert not bad, f"spawns that failed: {bad}"
hits = [s.get("progressMessage") for s in bake if s.get("remoteCacheHit")]
if sys.argv[3] == "executed":
    local = [(s.get("progressMessage"), s.get("runner")) for s in bake if s.get("runner") != "remote"]
    assert not local, f"spawns not executed remotely: {local}"
    assert not hits, f"remote cache hits where every action must execute: {hits}"
    print(f"{len(bake)} bake spawns in the execution log, runner remote, none a cache hit")
else:
    assert len(hits) == len(bake), f"{len(bake) - len(hits)} spawns not remote cache hits"
    print(f"{len(bake)} bake spawns in the execution log, every one a remote cache hit")
PY
}
check_log "$WORK/exec.json" "$ACTIONS" executed
"$PY" - "$WORK/bot.jsonl" "$ACTIONS" <<'PY'
import json, sys
events = [json.loads(l) for l in open(sys.argv[1])]
done = [e for e in events if e["event"] == "completed"]
bad = [e for e in done if e["status"] != "OK" or e["exit_code"] != 0]
assert not bad, f"leases that failed: {bad}"
assert len(done) == int(sys.argv[2]), f"the bot completed {len(done)} leases for {sys.argv[2]} actions"
bots = sorted({e["bot"] for e in done})
work = sum(e["seconds"] for e in done)
print(f"the bot completed {len(done)} leases (exit 0) in {len(bots)} sessions; "
      f"{work:.1f} s of lease time (fetch + run + upload)")
PY
cp bazel-bin/scene.bake "$WORK/remote.bake"
secs() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.1f", (b - a) / 1e9 }'; }
echo "remote-executed build: $(secs "$S" "$E") s wall"

echo "== against the single-process bake"
S=$(date +%s%N)
"$BAKE" -q src/scene.eco --sky src/sky.hdr --pipeline ci --no-cache -o "$WORK/reference.bake"
E=$(date +%s%N)
echo "bake SCENE.eco: $(secs "$S" "$E") s wall"
cmp "$WORK/reference.bake" "$WORK/remote.bake"
echo "pack identical to bake SCENE.eco ($(stat -c %s "$WORK/remote.bake") bytes)"

echo "== bazel clean, build again: every action a remote cache hit (results the bot reported)"
bz clean
bz_build "$WORK/again.log" //:scene "${FLAGS[@]}" --execution_log_json_file="$WORK/again.json"
grep -E "processes" "$WORK/again.log"
check_log "$WORK/again.json" "$ACTIONS" cached
cmp "$WORK/remote.bake" bazel-bin/scene.bake
LEASES=$(grep -c '"event": "completed"' "$WORK/bot.jsonl")
[ "$LEASES" = "$ACTIONS" ] || { echo "the bot ran $LEASES leases, expected $ACTIONS (none for cache hits)"; exit 1; }

echo "== for comparison: bazel clean, the same build with local spawns and no server"
bz clean
S=$(date +%s%N)
bz build //:scene --spawn_strategy=local --jobs=8 --noshow_progress > "$WORK/local.log" 2>&1 \
  || { cat "$WORK/local.log"; echo "FAIL: the local build"; exit 1; }
E=$(date +%s%N)
grep -E "processes|Elapsed" "$WORK/local.log"
grep -q "^INFO: $ACTIONS processes: $ACTIONS local\.$" "$WORK/local.log" \
  || { echo "the local build did not run $ACTIONS local actions"; cat "$WORK/local.log"; exit 1; }
cmp "$WORK/remote.bake" bazel-bin/scene.bake
echo "local build: $(secs "$S" "$E") s wall, same pack"

echo "PASS: Bazel 2.1.0 + BuildGrid 0.4.4 (PostgreSQL scheduler) + reapi-bot.py: $ACTIONS/$ACTIONS actions executed remotely ($LEASES leases), then $ACTIONS/$ACTIONS remote cache hits; pack identical to bake SCENE.eco ($(( $(date +%s) - T0 )) s in all)"

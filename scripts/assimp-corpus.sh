#!/usr/bin/env bash
# Real files no one here wrote: ingest every 3DS, OBJ and glTF 2 model of Debian's
# `assimp-testmodels` (the Open Asset Import Library's test corpus) with `bake ingest` and
# compare triangle counts with `assimp info` (package `assimp-utils`).
#
# Checks, per file:
#   - bake never panics (exit 101) nor dies from a signal;
#   - deliberately broken files (under invalid/, and the glTF2 folders IndexOutOfRange,
#     BoxWithInfinites, MissingBin, RecursiveNodes) are rejected with a non-zero exit and a
#     message naming the file;
#   - where assimp reads the file, our triangle count (from `bake dump --json`) equals assimp's.
#     assimp's count: from `assimp info FILE -r` (no post-processing) when the raw primitives are
#     all triangles (exact, and immune to assimp's instance merging); otherwise from
#     `assimp info FILE` (which triangulates). Either way it is the sum over the printed node
#     hierarchy of the faces of the `triangle` meshes each node refers to, since bake flattens
#     the hierarchy into one mesh (instances included). Lines and points are skipped by bake.
# Exit status: 0 when all checks pass, 1 on any panic, accepted broken file, or triangle-count
# mismatch that is not in the ALLOW list below (each entry says why it differs).
#
# Usage: scripts/assimp-corpus.sh [-v]      (BAKE=path/to/bake to skip the cargo build;
#        ASSIMP_CORPUS_DIR=dir for the download cache, default target/assimp-corpus)
set -u
ROOT=$(cd "$(dirname "$0")/.." && pwd)
CACHE=${ASSIMP_CORPUS_DIR:-$ROOT/target/assimp-corpus}
VERBOSE=${1:-}

# Known, explained differences: "path relative to the models folder|reason".
ALLOW=(
  "OBJ/box_longline.obj|a 936-vertex polygon repeating 1 2 3 4: half of its fan triangles are degenerate; assimp's FindDegenerates turns them into lines, bake keeps them"
  "OBJ/number_formats.obj|malformed numbers such as '3.1+e2' (line 11): assimp reads the prefix 3.1, bake rejects the file naming the line"
  "glTF2/draco/2CylinderEngine.gltf|Draco compression (KHR_draco_mesh_compression) is not supported: bake rejects it naming the extension"
)

# Broken on purpose: bake must reject these with a clear message.
is_broken() {
  case "$1" in
    invalid/*|glTF2/IndexOutOfRange/*|glTF2/BoxWithInfinites*|glTF2/MissingBin/*|glTF2/RecursiveNodes/*) return 0 ;;
  esac
  return 1
}

allowed() {
  local e
  for e in "${ALLOW[@]}"; do
    if [ "${e%%|*}" = "$1" ]; then echo "${e#*|}"; return 0; fi
  done
  return 1
}

fetch_corpus() {
  if [ ! -d "$CACHE/root/usr/share/assimp/models" ]; then
    mkdir -p "$CACHE"
    (cd "$CACHE" && { apt-get download assimp-testmodels >/dev/null 2>&1 ||
        { [ "$(id -u)" = 0 ] && apt-get update -qq && apt-get download assimp-testmodels >/dev/null; }; } &&
      dpkg-deb -x assimp-testmodels_*.deb root) || {
      echo "assimp-corpus: cannot fetch assimp-testmodels (apt-get download)" >&2; exit 2; }
  fi
  if ! command -v assimp >/dev/null; then
    if [ "$(id -u)" = 0 ]; then apt-get install -y -qq assimp-utils >/dev/null; fi
  fi
  command -v assimp >/dev/null || { echo "assimp-corpus: assimp (assimp-utils) not installed" >&2; exit 2; }
}

build_bake() {
  if [ -z "${BAKE:-}" ]; then
    (cd "$ROOT" && cargo build --quiet --bin bake) || exit 2
    BAKE="${CARGO_TARGET_DIR:-$ROOT/target}/debug/bake"
  fi
}

# Sum over the node hierarchy of the faces of the `triangle` meshes each node refers to (bake
# flattens the hierarchy, so a mesh used by two nodes counts twice, as in bake's output).
count_node_triangles() {
  awk '
    /^Meshes:  \(name\)/ { table = 1; next }
    table && /^ *$/ { table = 0 }
    table && /^ +[0-9]+ \(.*\): \[/ {
      idx = $1; row = $0; sub(/.*\[/, "", row); split(row, a, /[\/|\]]/)
      faces[idx] = a[3] + 0; t = a[4]; gsub(/ /, "", t); type[idx] = t; next
    }
    /^Node hierarchy:/ { nodes = 1; next }
    nodes && match($0, /\(mesh(es)? [0-9, ]+\)/) {
      s = substr($0, RSTART, RLENGTH); gsub(/[^0-9,]/, "", s); n = split(s, m, ",")
      for (i = 1; i <= n; i++) if (type[m[i]] == "triangle") total += faces[m[i]]
    }
    END { print total + 0 }'
}

# Triangle count by assimp, or empty when assimp cannot read the file.
assimp_triangles() {
  local raw full
  raw=$(timeout 60 assimp info "$1" -r 2>/dev/null) || return 0
  if echo "$raw" | grep -q '^Primitive Types: *triangles$'; then
    echo "$raw" | count_node_triangles
    return 0
  fi
  full=$(timeout 60 assimp info "$1" 2>/dev/null) || return 0
  echo "$full" | count_node_triangles
}

bake_triangles() {
  "$BAKE" dump "$1" --json 2>/dev/null | grep -oE '"triangles": *[0-9]+' | grep -oE '[0-9]+' |
    awk '{s += $1} END {print s + 0}'
}

main() {
  fetch_corpus
  build_bake
  local models="$CACHE/root/usr/share/assimp/models"
  TMP_DIR=$(mktemp -d)
  local tmp=$TMP_DIR
  trap 'rm -rf "$TMP_DIR"' EXIT
  local files=0 panics=0 compared=0 matched=0 allowed_n=0 failed=0 rejected=0 assimp_only=0
  printf '%-10s %8s %8s  %s\n' STATUS BAKE ASSIMP FILE
  while IFS= read -r -d '' f; do
    local rel=${f#"$models"/} out="$tmp/out.bake" rc msg ours theirs status note=""
    files=$((files + 1))
    rm -f "$out"
    timeout 120 "$BAKE" ingest "$f" -o "$out" --json --quiet >/dev/null 2>"$tmp/err"
    rc=$?
    msg=$(head -c 300 "$tmp/err" | tr '\n' ' ')
    if [ $rc -eq 101 ] || [ $rc -ge 124 ]; then
      status=PANIC; panics=$((panics + 1)); failed=$((failed + 1)); note="exit $rc: $msg"
      ours=-; theirs=-
    elif is_broken "$rel"; then
      ours=-; theirs=-
      if [ $rc -ne 0 ] && [ -n "$msg" ]; then
        status=REJECTED; rejected=$((rejected + 1)); note="$msg"
      else
        status=FAIL; failed=$((failed + 1)); note="broken file accepted (exit $rc)"
      fi
    else
      theirs=$(assimp_triangles "$f")
      if [ $rc -eq 0 ]; then ours=$(bake_triangles "$out"); else ours=-; note="$msg"; fi
      if [ -z "$theirs" ]; then
        theirs=-; status=NO-ASSIMP; assimp_only=$((assimp_only + 1))
        [ -z "$note" ] && note="assimp cannot read it; bake can"
      else
        compared=$((compared + 1))
        if [ "$ours" = "$theirs" ] || { [ "$ours" = - ] && [ "$theirs" = 0 ]; }; then
          status=OK; matched=$((matched + 1))
        elif reason=$(allowed "$rel"); then
          status=ALLOWED; allowed_n=$((allowed_n + 1)); note="$reason"
        else
          status=MISMATCH; failed=$((failed + 1))
        fi
      fi
    fi
    if [ "$status" != OK ] || [ -n "$VERBOSE" ]; then
      printf '%-10s %8s %8s  %s  %s\n' "$status" "$ours" "$theirs" "$rel" "$note"
    else
      printf '%-10s %8s %8s  %s\n' "$status" "$ours" "$theirs" "$rel"
    fi
  done < <(find "$models" -type f \( -iname '*.3ds' -o -iname '*.obj' -o \
             \( -path '*/glTF2/*' \( -iname '*.gltf' -o -iname '*.glb' \) \) \) -print0 | sort -z)
  echo
  echo "files: $files  compared with assimp: $compared  matched: $matched  allowed: $allowed_n"
  echo "broken files rejected: $rejected  assimp cannot read: $assimp_only  panics: $panics  failures: $failed"
  [ $failed -eq 0 ]
}

main

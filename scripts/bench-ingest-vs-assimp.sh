#!/usr/bin/env bash
# Whole-process ingest time of `bake ingest` against `assimp info` on the same files (default:
# the 3DS files of the assimp corpus fetched by scripts/assimp-corpus.sh). Each tool runs once per
# file per round; the best of ROUNDS rounds is reported (least disturbed by other load), per tool,
# in milliseconds per file, with the ratio. `assimp info -r` (import without post-processing) is
# measured too, since `assimp info` also runs assimp's full post-processing.
#
# Usage: BAKE=target/release/bake scripts/bench-ingest-vs-assimp.sh [FILES...]
#        ROUNDS=20 by default.
set -u
ROOT=$(cd "$(dirname "$0")/.." && pwd)
BAKE=${BAKE:-$ROOT/target/release/bake}
ROUNDS=${ROUNDS:-20}
if [ $# -eq 0 ]; then
  mapfile -d '' FILES < <(find "$ROOT/target/assimp-corpus/root/usr/share/assimp/models/3DS" \
    -type f -iname '*.3ds' -print0 | sort -z)
else
  FILES=("$@")
fi
[ ${#FILES[@]} -gt 0 ] || { echo "no input files (run scripts/assimp-corpus.sh first)" >&2; exit 2; }
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT

now() { date +%s%N; }

# Best-of-ROUNDS wall time in ns of running "$@ FILE" over all files.
best_ns() {
  local best=0 r t0 t1 f
  for ((r = 0; r < ROUNDS; r++)); do
    t0=$(now)
    for f in "${FILES[@]}"; do "$@" "$f" >/dev/null 2>&1; done
    t1=$(now)
    if [ $best -eq 0 ] || [ $((t1 - t0)) -lt $best ]; then best=$((t1 - t0)); fi
  done
  echo $best
}

bake_ingest() { "$BAKE" ingest "$1" -o "$TMP/out.bake" --quiet; }
assimp_info() { assimp info "$1"; }
assimp_raw() { assimp info "$1" -r; }

bytes=$(cat "${FILES[@]}" | wc -c)
n=${#FILES[@]}
b=$(best_ns bake_ingest)
a=$(best_ns assimp_info)
r=$(best_ns assimp_raw)
awk -v n="$n" -v bytes="$bytes" -v b="$b" -v a="$a" -v r="$r" 'BEGIN {
  printf "files: %d, %d bytes in all\n", n, bytes
  printf "bake ingest     %8.2f ms/file\n", b / n / 1e6
  printf "assimp info     %8.2f ms/file  (bake is %.1fx faster)\n", a / n / 1e6, a / b
  printf "assimp info -r  %8.2f ms/file  (bake is %.1fx faster)\n", r / n / 1e6, r / b
}'

#!/usr/bin/env bash
# Sky stage against Filament's cmgen on the same 2048×1024 Radiance sky (docs/PERFORMANCE.md, "Sky").
# Needs cmgen (Debian: libfilament-tools) and a release build of bake. Usage: scripts/bench-sky.sh [RUNS]
set -euo pipefail
runs=${1:-5}
bake=${BAKE:-target/release/bake}
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
"$bake" bench sky "$dir/sky.hdr" --write-sample 2048x1024 -q
wall() { # median wall seconds of $runs runs of "$@"
  for _ in $(seq "$runs"); do
    /usr/bin/time -f %e "$@" 2>&1 >/dev/null | tail -1
  done | sort -n | sed -n "$(( (runs + 1) / 2 ))p"
}
cpu() { # median CPU seconds (user + system) of $runs runs of "$@"
  for _ in $(seq "$runs"); do
    /usr/bin/time -f "%U %S" "$@" 2>&1 >/dev/null | tail -1 | awk '{print $1 + $2}'
  done | sort -n | sed -n "$(( (runs + 1) / 2 ))p"
}
echo "cmgen --sh=4 (SH only, whole process): $(wall cmgen --sh=4 --sh-output="$dir/cmgen.txt" --sh-window=no -q "$dir/sky.hdr") s"
echo "bake sky --sh-only (whole process):    $(wall "$bake" sky "$dir/sky.hdr" --sh-only -q) s"
echo "bake sky (cube, sun, SH, pack):        $(wall "$bake" sky "$dir/sky.hdr" -o "$dir/sky.bake" -q) s"
# The issue-19 job: decode, a 256² cube, SH (cmgen); decode, a 256² cube, the sun, SH, a pack (bake).
job_cmgen=(cmgen --sh=4 --size=256 --sh-output="$dir/job.txt" --sh-window=no -q "$dir/sky.hdr")
job_bake=("$bake" sky "$dir/sky.hdr" --face-size 256 -o "$dir/job.bake" -q)
echo "cmgen --sh=4 --size=256 (issue-19 job):  $(wall "${job_cmgen[@]}") s wall, $(cpu "${job_cmgen[@]}") s CPU"
echo "bake sky --face-size 256 (issue-19 job): $(wall "${job_bake[@]}") s wall, $(cpu "${job_bake[@]}") s CPU"
cmgen --sh=4 --sh-output="$dir/cmgen.txt" --sh-window=no -q "$dir/sky.hdr"
"$bake" bench sky "$dir/sky.hdr" --repeat "$runs" --cmgen-sh "$dir/cmgen.txt"

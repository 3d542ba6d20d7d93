#!/usr/bin/env bash
# Coverage-guided fuzzing of every reader and the pack container (docs/FUZZING.md) with libFuzzer,
# on the stable toolchain. The targets are built by plain `cargo build` with the flags cargo-fuzz
# 0.13 passes for `cargo fuzz build -s none -a` (copied from its `-v` output, listed in
# SANCOV below), so CI needs no cargo-fuzz install; `cargo fuzz run <target> -s none` works too.
#
#   scripts/fuzz.sh build                    build every target (release)
#   scripts/fuzz.sh smoke [SECONDS]          each target SECONDS (default 5) on its seed corpus; CI
#                                            (built in fuzz/Cargo.toml's dev profile)
#   scripts/fuzz.sh campaign SECONDS [T...]  each target (or the named ones) SECONDS, one after the
#                                            other at nice $FUZZ_NICE (default 19); corpus grows in
#                                            $FUZZ_WORK/<target>;
#                                            prints one line per target: executions, coverage
#
# Crashes, hangs (over 10 s) and allocations over 2 GiB (fuzz/src/lib.rs) stop a run and leave
# the input in $FUZZ_WORK/artifacts/<target>/; a non-zero exit says so. Targets are built
# without a sanitizer (`-s none`: Rust is memory-safe; what is sought is panics, hangs and huge
# allocations) and with debug assertions, so integer overflow is a crash too.
set -euo pipefail
cd "$(dirname "$0")/.."
export RUSTC_BOOTSTRAP=1
TARGETS=(txf max3ds eco sgi obj gltf raw hdr exr pack)
FUZZ_WORK=${FUZZ_WORK:-fuzz/work}
# Keep in step with the limits of issue 13: 2 GiB of RSS, 10 s per input.
LIBFUZZER=(-rss_limit_mb=2048 -timeout=10 -print_final_stats=1)

# PROFILE=dev (smoke) builds with `--dev`: seconds on the seeds need no release build, which
# took most of the fuzz step's time in CI; campaigns (and `build`) use release.
PROFILE=release

# What cargo-fuzz 0.13 adds to RUSTFLAGS for `-s none -a`: libFuzzer's coverage counters, value
# profiles of compares, `cfg(fuzzing)`, and debug assertions (with them, overflow checks).
SANCOV=(-Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4
  -Cllvm-args=-sanitizer-coverage-inline-8bit-counters -Cllvm-args=-sanitizer-coverage-pc-table
  -Cllvm-args=-sanitizer-coverage-trace-compares --cfg fuzzing
  -Cllvm-args=-simplifycfg-branch-fold-threshold=0 -Cllvm-args=-sanitizer-coverage-stack-depth
  -Cdebug-assertions)

# `--target` keeps the flags off build scripts and proc macros, as cargo-fuzz does.
build() {
  local profile=(--release)
  [ "$PROFILE" = dev ] && profile=()
  RUSTFLAGS="${SANCOV[*]}" cargo build --manifest-path fuzz/Cargo.toml --bins \
    --target x86_64-unknown-linux-gnu --target-dir "${CARGO_TARGET_DIR:-fuzz/target}" "${profile[@]}"
}

bin() {
  local dir=${CARGO_TARGET_DIR:-fuzz/target} sub=release
  [ "$PROFILE" = dev ] && sub=debug
  echo "$dir/x86_64-unknown-linux-gnu/$sub/$1"
}

# run TARGET SECONDS: fuzz TARGET from its seeds; grows $FUZZ_WORK/TARGET, never the seeds.
run() {
  local t=$1 secs=$2 log
  mkdir -p "$FUZZ_WORK/$t" "$FUZZ_WORK/artifacts/$t"
  log="$FUZZ_WORK/$t.log"
  local rc=0
  nice -n "${FUZZ_NICE:-19}" "$(bin "$t")" "${LIBFUZZER[@]}" -max_total_time="$secs" \
    -artifact_prefix="$FUZZ_WORK/artifacts/$t/" "$FUZZ_WORK/$t" "fuzz/corpus/$t" >"$log" 2>&1 || rc=$?
  local execs cov ft
  execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' || echo 0)
  cov=$(grep -o 'cov: [0-9]*' "$log" | tail -1 | grep -o '[0-9]*' || echo 0)
  ft=$(grep -o 'ft: [0-9]*' "$log" | tail -1 | grep -o '[0-9]*' || echo 0)
  printf '%-7s executions %12s  cov %6s  ft %6s  corpus %5s  rc %s\n' "$t" "${execs:-0}" "${cov:-0}" "${ft:-0}" \
    "$(ls "$FUZZ_WORK/$t" | wc -l)" "$rc"
  if [ "$rc" = 0 ] && [ "${cov:-0}" = 0 ]; then
    echo "$t: no coverage reported: the target was built without libFuzzer's instrumentation" >&2
    return 1
  fi
  if [ "$rc" != 0 ]; then
    echo "$t: the fuzzer stopped (crash, hang or huge allocation); see $log and $FUZZ_WORK/artifacts/$t/" >&2
    return 1
  fi
}

case "${1:-}" in
  build) build ;;
  smoke)
    PROFILE=dev
    build
    secs=${2:-5}
    status=0
    for t in "${TARGETS[@]}"; do run "$t" "$secs" || status=1; done
    exit $status
    ;;
  campaign)
    secs=${2:?seconds per target}
    shift 2
    [ $# -gt 0 ] && TARGETS=("$@")
    status=0
    for t in "${TARGETS[@]}"; do run "$t" "$secs" || status=1; done
    exit $status
    ;;
  *) sed -n '2,18p' "$0"; exit 2 ;;
esac

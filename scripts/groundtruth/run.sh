#!/usr/bin/env bash
# The ground-truth harness: creates its virtual environment (target/groundtruth-venv, the pinned
# requirements.txt) on first use, then runs groundtruth.py with the arguments given
# (`run.sh venv` only creates the environment: .ci/run does that while the compiler works).
# Needs python3-venv, and Debian's libllvm19 for Mitsuba's llvm_ad_rgb variant (else scalar_rgb).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/../.." && pwd)"
venv="${GROUNDTRUTH_VENV:-$root/target/groundtruth-venv}"
if [ ! -x "$venv/bin/python" ] || ! cmp -s "$here/requirements.txt" "$venv/requirements.txt"; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet --disable-pip-version-check -r "$here/requirements.txt"
  cp "$here/requirements.txt" "$venv/requirements.txt"
fi
if [ "${1:-}" = venv ]; then
  echo "the ground-truth venv in $venv"
  exit 0
fi
# Mitsuba's LLVM backend looks for libLLVM by name; Debian ships it versioned.
if [ -z "${DRJIT_LIBLLVM_PATH:-}" ]; then
  for f in /usr/lib/x86_64-linux-gnu/libLLVM-19.so /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1 /usr/lib/llvm-19/lib/libLLVM.so.1; do
    if [ -e "$f" ]; then export DRJIT_LIBLLVM_PATH="$f"; break; fi
  done
fi
exec "$venv/bin/python" "$here/groundtruth.py" "$@"

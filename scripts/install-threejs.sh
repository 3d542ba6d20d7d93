#!/usr/bin/env bash
# three.js (npm `three`, pinned in scripts/threejs/package-lock.json) into target/threejs, where
# scripts/threejs/check.js and tests/export_threejs.rs look for it (override: THREEJS=DIR holding
# node_modules/three). Needs npm; Chromium (/usr/bin/chromium or $CHROMIUM) runs the page.
set -euo pipefail
cd "$(dirname "$0")/.."
DIR=target/threejs
VERSION=$(node -p 'require("./scripts/threejs/package.json").dependencies.three')
PKG="$DIR/node_modules/three/package.json"
if [ -f "$PKG" ] && [ "$(node -p "require('./$PKG').version")" = "$VERSION" ]; then
  echo "three $VERSION already in $DIR"
  exit 0
fi
mkdir -p "$DIR"
cp scripts/threejs/package.json scripts/threejs/package-lock.json "$DIR/"
(cd "$DIR" && npm ci --no-audit --no-fund --loglevel=error)
echo "three $VERSION installed in $DIR"

#!/usr/bin/env bash
# The Khronos glTF validator (npm gltf-validator, pinned) into target/gltf-validator, where
# tests/export.rs looks for it (override: GLTF_VALIDATOR=DIR of the package). Needs npm.
set -euo pipefail
cd "$(dirname "$0")/.."
VERSION=2.0.0-dev.3.10
DIR=target/gltf-validator
PKG="$DIR/node_modules/gltf-validator/package.json"
if [ -f "$PKG" ] && grep -q "\"version\": \"$VERSION\"" "$PKG"; then
  echo "gltf-validator $VERSION already in $DIR"
  exit 0
fi
mkdir -p "$DIR"
npm install --prefix "$DIR" --no-audit --no-fund --no-save --loglevel=error "gltf-validator@$VERSION"
echo "gltf-validator $VERSION installed in $DIR"

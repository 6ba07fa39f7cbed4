#!/usr/bin/env sh
# Rebuild the vendored front-end bundle from the pinned npm packages (package-lock.json).
# The result is committed, so neither the app nor its tests need npm or a network at run time.
set -eu
cd "$(dirname "$0")"
out=../src/skinloc/app/static/vendor
npm ci --no-audit --no-fund
npx esbuild vendor-entry.js --bundle --format=esm --minify --legal-comments=none \
    --outfile="$out/three.bundle.min.js"
cp node_modules/three/LICENSE "$out/three.LICENSE.txt"
version=$(node -p "JSON.parse(require('fs').readFileSync('node_modules/three/package.json')).version")
printf 'three.js %s (npm package "three", MIT licence: three.LICENSE.txt), with OrbitControls,\nbundled by web/build-vendor.sh with esbuild. Do not edit: rebuild it.\n' "$version" \
    > "$out/README.txt"
echo "wrote $out/three.bundle.min.js (three $version)"

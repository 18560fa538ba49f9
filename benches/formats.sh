#!/usr/bin/env bash
# Every camera format against its COLMAP model on the bundled sample (issue 25): texture the
# scene through each, compare the texture's bytes with the COLMAP model's and print held-out
# PSNR / 1-NCC. The undistorted sample (for OpenMVS and NVM, which hold no COLMAP distortion)
# is made by calib/undistorted/make.py (pycolmap).
#
#   cargo build --release && pip install pycolmap==4.2.1 numpy pillow
#   bash benches/formats.sh [work]
set -euo pipefail
cd "$(dirname "$0")/.."
B=target/release/scantex
W=${1:-/tmp/scantex_formats}
rm -rf "$W"; mkdir -p "$W"
python3 calib/undistorted/make.py "$W/undistorted" 2>/dev/null
run() { # name scene [texture args...]
  local name=$1 scene=$2; shift 2
  "$B" texture "$scene" "$@" -o "$W/$name" -q > /dev/null
  "$B" eval --mesh "$W/$name/model.obj" samples/torus/heldout --gain-fit --json "$W/$name.json" > /dev/null
  python3 -c "import json; m=json.load(open('$W/$name.json'))['mean']; print(f\"$name: {m['psnr']:.4f} dB, 1-NCC {m['one_minus_ncc']:.5f}\")"
}
same() { cmp -s "$W/$1/model.png" "$W/$2/model.png" && echo "  $2: same model.png bytes as $1" || echo "  $2: model.png DIFFERS from $1"; }
run colmap samples/torus
run bundler samples/torus --colmap calib/bundler/torus.out
run meshroom samples/torus --colmap calib/meshroom/torus_cameras.sfm
same colmap bundler; same colmap meshroom
run undistorted_colmap "$W/undistorted"
for f in torus_v0 torus_v1 torus_v7_rig; do run "$f" "$W/undistorted" --colmap "calib/openmvs/$f.mvs"; done
run nvm "$W/undistorted" --colmap calib/nvm/torus.nvm
for f in torus_v0 torus_v1 torus_v7_rig nvm; do same undistorted_colmap "$f"; done

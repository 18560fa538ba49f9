#!/bin/sh
# Stage 6 against the fills it replaces, on a scene made by
#   scantex sample --from-mesh ... --unseen-sector 200 --heldout 8 -o SCENE
# Usage: sh benches/stage6.sh SCENE [SCANTEX_BINARY [BASELINE_BINARY]]. Prints wall time,
# peak memory and the held-out scores (all pixels, where no input photograph saw the
# surface, and the same where they did) per fill; with a baseline binary (a previous release), its default run first.
# On a scene without held-out unseen masks (the bundled sample) only the first table prints.
# Fills other than the default need a binary with stage 6.
set -eu
scene=$1
bin=${2:-target/release/scantex}
base=${3:-}
out=$(mktemp -d)
# A flat exemplar: stage 6 with no detail, i.e. the harmonic low band alone.
python3 - "$out/flat.png" <<'PY'
import struct, sys, zlib
def chunk(t, d):
    return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)
raw = b"".join(b"\0" + bytes([128]) * 192 for _ in range(64))
png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 64, 64, 8, 2, 0, 0, 0))
png += chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
open(sys.argv[1], "wb").write(png)
PY
run_with() {
  b=$1; name=$2; shift 2
  /usr/bin/time -f "$name: %e s wall, %M KB peak" "$b" texture "$scene" -o "$out/$name" -q "$@"
  "$bin" eval "$scene/heldout" --mesh "$out/$name/model.obj" --gain-fit | grep -E "^mean|^image"
}
run() { run_with "$bin" "$@"; }
if [ -n "$base" ]; then run_with "$base" baseline; fi
run vertex --exemplar off --min-depth inf
run restore --exemplar off --min-depth inf --max-hole 0
run lowband --exemplar "$out/flat.png"
run stage6
rm -rf "$out"

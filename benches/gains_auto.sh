#!/bin/sh
# Every --gains x --delight candidate against the default (auto), on scenes that provoke
# delighting's failure (albedo that follows the normal) and on ones where it helps.
# Usage: sh benches/gains_auto.sh [SCANTEX_BINARY [SHEET_DIR]]. Generates the scenes in a
# temporary directory (the corset and the avocado from ../shared/data/scans when present),
# textures each with every candidate, and prints held-out PSNR (gain-fitted, mean of the
# held-out views; the sample's held-out views are lit flat, so this measures albedo), the
# choice auto made and the wall time of auto against `--gains lighting --delight global` (the
# previous default). With SHEET_DIR, writes one contact sheet per scene there: held-out
# photograph | truth | previous default | auto, rendered from the first held-out view.
set -eu
bin=${1:-target/release/scantex}
sheets=${2:-}
root=$(cd "$(dirname "$0")/.." && pwd)
data=$root/../shared/data/scans
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$bin" sample -o "$work/torus_fixed" --fixed-light 2>/dev/null
"$bin" sample --object jar -o "$work/jar" 2>/dev/null
"$bin" sample --object jar --fixed-light -o "$work/jar_fixed" 2>/dev/null
"$bin" sample --object jar --fixed-light --gain-range 0 -o "$work/jar_nogain" 2>/dev/null
scenes="$root/samples/torus $work/torus_fixed $work/jar $work/jar_fixed $work/jar_nogain"
if [ -f "$data/corset/Corset.gltf" ]; then
  "$bin" sample --from-mesh "$data/corset/Corset.gltf" --up y --photos 24 -o "$work/corset" 2>/dev/null
  scenes="$scenes $work/corset"
fi
if [ -f "$data/avocado/Avocado.gltf" ]; then
  "$bin" sample --from-mesh "$data/avocado/Avocado.gltf" --up y -o "$work/avocado" 2>/dev/null
  scenes="$scenes $work/avocado"
fi
psnr() { "$bin" eval "$1/heldout" --mesh "$2/model.obj" --gain-fit | awk '/^mean/ {print $3; exit}'; }
echo "| scene | off/off | off/steps | off/global | exposure/off | exposure/steps | exposure/global | lighting/off | lighting/steps | lighting/global | auto | auto chose | auto s | lighting/global s |"
echo "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
for s in $scenes; do
  name=$(basename "$s")
  row="| $name"
  for g in off exposure lighting; do
    for d in off steps global; do
      o=$work/out/$name/${g}_$d
      /usr/bin/time -f "%e" -o "$work/t" "$bin" texture "$s" -o "$o" -q --gains $g --delight $d
      row="$row | $(psnr "$s" "$o")"
      if [ $g = lighting ] && [ $d = global ]; then t_old=$(cat "$work/t"); fi
    done
  done
  o=$work/out/$name/auto
  /usr/bin/time -f "%e" -o "$work/t" "$bin" texture "$s" -o "$o" -q
  chose=$(python3 -c "import json,sys; g=json.load(open(sys.argv[1]))['gains']; print(g['model']+'/'+g['delight']+(' (one light)' if g['shared_light'] else ''))" "$o/report.json")
  echo "$row | **$(psnr "$s" "$o")** | $chose | $(cat "$work/t") | $t_old |"
  if [ -n "$sheets" ]; then
    mkdir -p "$sheets"
    view=$(ls "$s/heldout/images" | head -1)
    for k in truth old auto; do
      case $k in
        truth) m=$s/truth/model.glb ;;
        old) m=$work/out/$name/lighting_global/model.obj ;;
        auto) m=$o/model.obj ;;
      esac
      "$bin" render "$s/heldout" --mesh "$m" -o "$work/render_$k" >/dev/null 2>&1
    done
    python3 - "$s/heldout/images/$view" "$work" "${view%.*}.png" "$sheets/gains_$name.png" <<'PY'
import sys
from PIL import Image
photo, work, png, out = sys.argv[1:]
ims = [Image.open(photo).convert("RGB")] + [
    Image.open(f"{work}/render_{k}/{png}").convert("RGB") for k in ("truth", "old", "auto")]
w, h = ims[0].size
sheet = Image.new("RGB", (4 * w, h))
for i, im in enumerate(ims):
    sheet.paste(im, (i * w, 0))
sheet.resize((4 * w // 2, h // 2), Image.LANCZOS).save(out)
PY
  fi
done

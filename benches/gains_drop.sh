#!/bin/sh
# How steady the automatic gains and delighting choice is: the scene textured once per
# photograph with that photograph left out, printing per run the choice and the held-out
# PSNR / 1-NCC (`scantex eval --gain-fit`), for one binary or two side by side.
# Usage: sh benches/gains_drop.sh SCENE BIN [OTHER_BIN]
set -eu
scene=$1
a=$2
b=${3:-}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
run() {
  bin=$1; s=$2; o=$3
  "$bin" texture "$s" -o "$o" -q --skip-missing >/dev/null 2>&1
  g=$(python3 -c "import json,sys; g=json.load(open(sys.argv[1]))['gains']; print(g['model'] + '/' + g['delight'])" "$o/report.json")
  e=$("$bin" eval "$s/heldout" --mesh "$o/model.obj" --gain-fit | awk '/^mean/ {print $3 " / " $5; exit}')
  printf '%s %s' "$g" "$e"
}
if [ -n "$b" ]; then
  echo "| left out | $a | $b |"
  echo "| --- | --- | --- |"
else
  echo "| left out | $a |"
  echo "| --- | --- |"
fi
for p in "$scene"/images/*; do
  name=$(basename "$p")
  rm -rf "$work/s"
  cp -r "$scene" "$work/s"
  rm "$work/s/images/$name"
  row="| $name | $(run "$a" "$work/s" "$work/a")"
  if [ -n "$b" ]; then row="$row | $(run "$b" "$work/s" "$work/b")"; fi
  echo "$row |"
done

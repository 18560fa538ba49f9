#!/usr/bin/env python3
"""Seam visibility and held-out quality of the merge modes (issue 6).

    cargo build --release
    python3 benches/merge_compare.py [--quick]     # prints markdown tables

Scenes: the bundled torus sample and the corset (`scantex sample --from-mesh
../shared/data/scans/corset/Corset.gltf --up y --photos 24`), both with +-25% per-photograph
exposure and white balance and Lambert light from a random direction per photograph, and a
control corset whose photographs differ in viewpoint only. For every variant: the seam ratios from
`report.json` (view boundaries and chart borders, 1 = invisible; see src/seams.rs), held-out
PSNR (gain-fitted) and 1 - NCC from `scantex eval --gain-fit`, and the resample+merge stage's
seconds. Standard library only.
"""
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, "..", "shared", "data")
BIN = os.path.join(ROOT, "target", "release", "scantex")

# Levels are explicit so that the rows mean the same whatever the default is.
VARIANTS = [
    ("none", ["--merge", "none"]),
    ("average", ["--merge", "average"]),
    ("multiband, best-view masks, levels 2", ["--levels", "2"]),
    ("multiband, best-view masks, levels 4", ["--levels", "4"]),
    ("multiband, best-view masks, levels 6", ["--levels", "6"]),
    ("multiband, levels 2, --no-seam-levelling", ["--levels", "2", "--no-seam-levelling"]),
    ("multiband, levels 6, --no-seam-levelling", ["--levels", "6", "--no-seam-levelling"]),
    ("multiband, paper masks, levels 6", ["--merge-masks", "paper", "--levels", "6"]),
    ("multiband, weighted masks, levels 6", ["--merge-masks", "weighted", "--levels", "6"]),
    ("none, --no-exposure-solve", ["--merge", "none", "--no-exposure-solve"]),
    ("average, --no-exposure-solve", ["--merge", "average", "--no-exposure-solve"]),
    ("multiband, levels 6, --no-exposure-solve", ["--levels", "6", "--no-exposure-solve"]),
]
QUICK = 5
# The control scene: photographs that differ in nothing but viewpoint, so every seam ratio
# above its value here is the merge's doing, and the rest is the measure's floor.
CONTROL = [
    ("none", ["--merge", "none", "--no-exposure-solve"]),
    ("average", ["--merge", "average", "--no-exposure-solve"]),
    ("multiband, levels 2", ["--levels", "2", "--no-exposure-solve"]),
    ("multiband, levels 6", ["--levels", "6", "--no-exposure-solve"]),
]


def run(args):
    r = subprocess.run([BIN] + args, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"scantex {' '.join(args)} failed:\n{r.stderr}")


def measure(scene, extra, tmp):
    out = os.path.join(tmp, "out")
    run(["texture", scene, "-q", "-o", out] + extra)
    js = os.path.join(tmp, "eval.json")
    run(["eval", "--mesh", os.path.join(out, "model.obj"), "--gain-fit", "--json", js,
         os.path.join(scene, "heldout")])
    with open(js) as f:
        mean = json.load(f)["mean"]
    with open(os.path.join(out, "report.json")) as f:
        rep = json.load(f)
    secs = next(s["seconds"] for s in rep["stages"] if s["stage"].startswith("resample"))
    return rep["seams"], mean, secs


def main():
    if not os.path.exists(BIN):
        sys.exit("build first: cargo build --release")
    variants = VARIANTS[:QUICK] if "--quick" in sys.argv else VARIANTS
    with tempfile.TemporaryDirectory() as tmp:
        mesh = os.path.join(DATA, "scans", "corset", "Corset.gltf")
        corset = os.path.join(tmp, "corset")
        run(["sample", "--from-mesh", mesh, "--up", "y", "--photos", "24", "-o", corset])
        clean = os.path.join(tmp, "corset_clean")
        run(["sample", "--from-mesh", mesh, "--up", "y", "--photos", "24", "--gain-range", "0",
             "--fixed-light", "-o", clean])
        for name, scene, rows in [
                ("torus (samples/torus)", os.path.join(ROOT, "samples", "torus"), variants),
                ("corset (24 photographs, 4 held out)", corset, variants),
                ("control: corset with identical exposure, white balance and light", clean,
                 CONTROL)]:
            print(f"\n### {name}\n")
            print("| variant | view-boundary ratio (local) | (global) | chart-border ratio "
                  "| PSNR dB | 1 - NCC | resample+merge s |")
            print("|---|---|---|---|---|---|---|")
            for label, extra in rows:
                s, m, secs = measure(scene, extra, tmp)
                print(f"| {label} | {s['view_boundary_ratio']:.3f} "
                      f"| {s['view_boundary_ratio_global']:.2f} | {s['chart_border_ratio']:.3f} "
                      f"| {m['psnr']:.2f} | {m['one_minus_ncc']:.4f} | {secs:.1f} |", flush=True)


if __name__ == "__main__":
    main()

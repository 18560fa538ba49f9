#!/usr/bin/env python3
"""Seam visibility and held-out quality of the merge modes (issue 6).

    cargo build --release
    python3 benches/merge_compare.py [--quick]     # prints markdown tables

Scenes: the bundled torus sample and the corset (`scantex sample --from-mesh
../shared/data/scans/corset/Corset.gltf --up y --photos 24`), both with +-25% per-photograph
exposure and white balance and Lambert light. For every variant: the seam ratios from
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
    ("multiband, best-view masks, levels 2 (default)", []),
    ("multiband, paper masks, levels 6", ["--merge-masks", "paper", "--levels", "6"]),
    ("multiband, weighted masks, levels 6", ["--merge-masks", "weighted", "--levels", "6"]),
    ("multiband, best-view masks, levels 6", ["--levels", "6"]),
    ("multiband, best-view masks, levels 4", ["--levels", "4"]),
    ("none, --no-exposure-solve", ["--merge", "none", "--no-exposure-solve"]),
    ("average, --no-exposure-solve", ["--merge", "average", "--no-exposure-solve"]),
    ("multiband, levels 6, --no-exposure-solve", ["--levels", "6", "--no-exposure-solve"]),
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
    variants = VARIANTS[:3] if "--quick" in sys.argv else VARIANTS
    with tempfile.TemporaryDirectory() as tmp:
        corset = os.path.join(tmp, "corset")
        run(["sample", "--from-mesh", os.path.join(DATA, "scans", "corset", "Corset.gltf"),
             "--up", "y", "--photos", "24", "-o", corset])
        for name, scene in [("torus (samples/torus)", os.path.join(ROOT, "samples", "torus")),
                            ("corset (24 photographs, 4 held out)", corset)]:
            print(f"\n### {name}\n")
            print("| variant | view-boundary ratio | chart-border ratio | PSNR dB | 1 - NCC | resample+merge s |")
            print("|---|---|---|---|---|---|")
            for label, extra in variants:
                s, m, secs = measure(scene, extra, tmp)
                print(f"| {label} | {s['view_boundary_ratio']:.3f} | {s['chart_border_ratio']:.3f} "
                      f"| {m['psnr']:.2f} | {m['one_minus_ncc']:.4f} | {secs:.1f} |", flush=True)


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Seam visibility and held-out quality of the merge modes (issue 6).

    cargo build --release
    python3 benches/merge_compare.py [--quick]     # prints markdown tables

Scenes: the bundled torus sample and the corset (`scantex sample --from-mesh
../shared/data/scans/corset/Corset.gltf --up y --photos 24`), both with +-25% per-photograph
exposure and white balance and Lambert light from a random direction per photograph, and a
control corset whose photographs differ in viewpoint only, and a misregistered corset (each
training photograph's principal point moved 1 px in a random direction, the held-out views
exact). For every variant: the seam ratios from
`report.json` (view boundaries and chart borders, 1 = invisible; see src/seams.rs), held-out
PSNR (gain-fitted) and 1 - NCC from `scantex eval --gain-fit`, and the resample+merge stage's
seconds. Standard library only.
"""
import json
import math
import os
import random
import shutil
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
    ("multiband, levels 2, --fine-exponent inf (finest band: best view alone)",
     ["--levels", "2", "--fine-exponent", "inf"]),
    ("multiband, levels 2, --fine-exponent 1", ["--levels", "2", "--fine-exponent", "1"]),
    ("multiband, levels 2, --fine-exponent 4", ["--levels", "2", "--fine-exponent", "4"]),
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
QUICK = 6
# The control scene: photographs that differ in nothing but viewpoint, so every seam ratio
# above its value here is the merge's doing, and the rest is the measure's floor.
CONTROL = [
    ("none", ["--merge", "none", "--no-exposure-solve"]),
    ("average", ["--merge", "average", "--no-exposure-solve"]),
    ("multiband, levels 2", ["--levels", "2", "--no-exposure-solve"]),
    ("multiband, levels 2, --fine-exponent inf",
     ["--levels", "2", "--fine-exponent", "inf", "--no-exposure-solve"]),
    ("multiband, levels 6", ["--levels", "6", "--no-exposure-solve"]),
]
# Misregistered photographs: the corset with every training photograph's principal point moved
# by 1 px in a random direction (held-out views exact), where averaging fine detail across
# photographs would blur or ghost it.
MISREGISTERED = [
    ("average", ["--merge", "average"]),
    ("multiband, levels 2", ["--levels", "2"]),
    ("multiband, levels 2, --fine-exponent inf", ["--levels", "2", "--fine-exponent", "inf"]),
    ("multiband, levels 2, --fine-exponent 1", ["--levels", "2", "--fine-exponent", "1"]),
    ("multiband, levels 2, --fine-exponent 0", ["--levels", "2", "--fine-exponent", "0"]),
]


def run(args):
    r = subprocess.run([BIN] + args, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"scantex {' '.join(args)} failed:\n{r.stderr}")


def misregister(scene, out, shift=1.0, seed=7):
    """A copy of `scene` (links, but the cameras) whose photographs' principal points are
    each moved by `shift` pixels in a random direction."""
    rng = random.Random(seed)
    os.makedirs(os.path.join(out, "sparse", "0"))
    for name in os.listdir(scene):
        if name != "sparse":
            os.symlink(os.path.join(scene, name), os.path.join(out, name))
    src = os.path.join(scene, "sparse", "0")
    for name in ("images.txt", "points3D.txt"):
        shutil.copy(os.path.join(src, name), os.path.join(out, "sparse", "0", name))
    lines = []
    with open(os.path.join(src, "cameras.txt")) as f:
        for line in f:
            p = line.split()
            if not line.startswith("#") and len(p) >= 7:
                # CAMERA_ID MODEL WIDTH HEIGHT f cx cy ...: every model the sampler writes
                # (SIMPLE_RADIAL) has cx, cy at 5 and 6.
                a = rng.uniform(0.0, 2.0 * math.pi)
                p[5] = repr(float(p[5]) + shift * math.cos(a))
                p[6] = repr(float(p[6]) + shift * math.sin(a))
                line = " ".join(p) + "\n"
            lines.append(line)
    with open(os.path.join(out, "sparse", "0", "cameras.txt"), "w") as f:
        f.writelines(lines)


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
    return rep["pages"][0]["seams"], mean, secs


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
        shifted = os.path.join(tmp, "corset_misregistered")
        misregister(corset, shifted)
        for name, scene, rows in [
                ("torus (samples/torus)", os.path.join(ROOT, "samples", "torus"), variants),
                ("corset (24 photographs, 4 held out)", corset, variants),
                ("control: corset with identical exposure, white balance and light", clean,
                 CONTROL),
                ("misregistered: the corset with each photograph's principal point 1 px off",
                 shifted, MISREGISTERED)]:
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

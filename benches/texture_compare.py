#!/usr/bin/env python3
"""Held-out comparison of `scantex texture` variants: `--method paper` against the default and
each of the default's departures from the paper turned off in turn.

    cargo build --release
    python3 benches/texture_compare.py            # prints markdown tables

Scenes:
  * torus: the bundled sample (16 photographs under Lambert light, +-25% exposure and white
    balance; 4 evenly lit held-out views);
  * corset: `scantex sample --from-mesh ../shared/data/scans/corset/Corset.gltf --up y
    --photos 24` (written to a temporary directory; 24 photographs, 4 held out);
  * floor_patch: leave-one-out on ../shared/data/colmap/floor_patch (texture from 4 real
    photographs, evaluate on the 5th, each in turn; mean over the five).
Every textured mesh is measured by `scantex eval --gain-fit` (PSNR and SSIM after one gain per
channel and image, 1 - NCC, completeness). Standard library only.
"""
import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, "..", "shared", "data")
BIN = os.path.join(ROOT, "target", "release", "scantex")

VARIANTS = [
    ("paper", ["--method", "paper"]),
    ("default (robust, gains lighting, delight, vertex consistency)", []),
    ("default, --no-delight", ["--no-delight"]),
    ("default, --gains exposure", ["--gains", "exposure"]),
    ("default, --gains off", ["--gains", "off"]),
    ("default, --consistency off", ["--consistency", "off"]),
    ("default, --consistency face", ["--consistency", "face"]),
    ("default, --weight-power 0 (equal weights)", ["--weight-power", "0"]),
    ("default, --weight-power 2", ["--weight-power", "2"]),
    ("paper, --gains lighting (delight)", ["--method", "paper", "--gains", "lighting"]),
]


def run(args):
    r = subprocess.run([BIN] + args, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"scantex {' '.join(args)} failed:\n{r.stderr}")
    return r


def texture_and_eval(tex_args, eval_args, tmp):
    out = os.path.join(tmp, "out")
    t = time.time()
    run(["texture", "-q", "-o", out] + tex_args)
    secs = time.time() - t
    js = os.path.join(tmp, "eval.json")
    run(["eval", "--mesh", os.path.join(out, "model.obj"), "--gain-fit", "--json", js] + eval_args)
    with open(js) as f:
        mean = json.load(f)["mean"]
    with open(os.path.join(out, "report.json")) as f:
        rep = json.load(f)
    return mean, secs, rep


def table(title, rows):
    print(f"\n### {title}\n")
    print("| variant | PSNR dB | SSIM | 1 - NCC | completeness | time s |")
    print("|---|---|---|---|---|---|")
    base = rows[0][1]["psnr"]
    for name, m, secs in rows:
        d = m["psnr"] - base
        print(
            f"| {name} | {m['psnr']:.2f} ({d:+.2f}) | {m['ssim']:.4f} | {m['one_minus_ncc']:.4f} "
            f"| {m['completeness']:.4f} | {secs:.1f} |"
        )


def synthetic(name, scene, tmp):
    rows = []
    for label, extra in VARIANTS:
        m, secs, _ = texture_and_eval([scene] + extra, [os.path.join(scene, "heldout")], tmp)
        rows.append((label, m, secs))
        print(f"{name}: {label}: {m['psnr']:.2f} dB", file=sys.stderr)
    table(name, rows)


def floor_patch(tmp):
    d = os.path.realpath(os.path.join(DATA, "colmap", "floor_patch", "dense", "0"))
    if not os.path.isdir(d):
        print("floor_patch: data missing, skipped", file=sys.stderr)
        return
    images = sorted(os.listdir(os.path.join(d, "images")))
    rows = []
    for label, extra in VARIANTS[:5]:
        acc = {"psnr": 0.0, "ssim": 0.0, "one_minus_ncc": 0.0, "completeness": 0.0}
        total = 0.0
        for held in images:
            train = os.path.join(tmp, "train")
            test = os.path.join(tmp, "test")
            for p in (train, test):
                if os.path.isdir(p):
                    for f in os.listdir(p):
                        os.remove(os.path.join(p, f))
                else:
                    os.makedirs(p)
            for im in images:
                os.symlink(os.path.join(d, "images", im), os.path.join(test if im == held else train, im))
            common = ["--colmap", os.path.join(d, "sparse"), "--skip-missing"]
            m, secs, _ = texture_and_eval(
                ["--mesh", os.path.join(d, "meshed-poisson.ply"), "--images", train] + common + extra,
                ["--images", test] + common,
                tmp,
            )
            for k in acc:
                acc[k] += m[k] / len(images)
            total += secs / len(images)
        rows.append((label, acc, total))
        print(f"floor_patch: {label}: {acc['psnr']:.2f} dB", file=sys.stderr)
    table("floor_patch, leave-one-out (mean of 5)", rows)


def main():
    if not os.path.exists(BIN):
        sys.exit("build first: cargo build --release")
    with tempfile.TemporaryDirectory() as tmp:
        synthetic("torus (samples/torus)", os.path.join(ROOT, "samples", "torus"), tmp)
        corset = os.path.join(tmp, "corset")
        run(["sample", "--from-mesh", os.path.join(DATA, "scans", "corset", "Corset.gltf"),
             "--up", "y", "--photos", "24", "-o", corset])
        synthetic("corset (24 photographs, 4 held out)", corset, tmp)
        floor_patch(tmp)


if __name__ == "__main__":
    main()

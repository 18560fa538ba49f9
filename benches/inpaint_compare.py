#!/usr/bin/env python3
"""scantex inpaint against cv2.inpaint (TELEA, NS; radius 5) on the textures of
../shared/data/textures, as they are and under an intensity ramp, with the masks of
calib/opencv/inpaint/ (5% and 15% scattered blobs, one 10% disc).

    cargo build --release
    python3 calib/opencv/inpaint.py      # once: masks + OpenCV's figures
    python3 benches/inpaint_compare.py [--method fast|paper] [--only brick] [--out DIR]

Prints one row per case and a summary against the targets (detail ratio 0.8-1.2 everywhere,
low-frequency PSNR within 1 dB of TELEA's).
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import cv2
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, "calib", "opencv"))
import inpaint as ref  # noqa: E402

BIN = os.path.join(ROOT, "target", "release", "scantex")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--method", default="fast")
    ap.add_argument("--only", default=None, help="texture name filter")
    ap.add_argument("--out", default=None, help="keep results here")
    ap.add_argument("--extra", default="", help="more scantex inpaint flags")
    args = ap.parse_args()
    with open(os.path.join(ROOT, "calib", "opencv", "inpaint.json")) as f:
        cases = json.load(f)["results"]
    tmp = args.out or tempfile.mkdtemp()
    os.makedirs(tmp, exist_ok=True)
    rows = []
    for c in cases:
        if args.only and args.only not in c["texture"]:
            continue
        truth = ref.load(c["path"], c["ramp"])
        mask = cv2.imread(os.path.join(ROOT, "calib", "opencv", "inpaint", c["mask_file"]), 0) > 127
        src = np.round(truth * 255).astype(np.uint8)
        tag = f"{c['texture']}_{'ramp' if c['ramp'] else 'flat'}_{c['mask']}"
        ip, op = os.path.join(tmp, tag + "_in.png"), os.path.join(tmp, tag + "_out.png")
        cv2.imwrite(ip, src)
        t = time.time()
        r = subprocess.run(
            [BIN, "inpaint", ip, "--mask", os.path.join(ROOT, "calib", "opencv", "inpaint", c["mask_file"]),
             "-o", op, "--method", args.method, "--json"] + args.extra.split(),
            capture_output=True, text=True)
        wall = time.time() - t
        if r.returncode != 0:
            print(tag, "FAILED", r.stderr, file=sys.stderr)
            continue
        rep = json.loads(r.stdout)
        res = cv2.imread(op, 0).astype(np.float64) / 255.0
        m = ref.metrics(truth, res, mask)
        rows.append({**c, "ours": m, "kappa": rep["kappa"], "seconds": rep["seconds"], "wall": wall})
        print(f"{tag:36s} k={rep['kappa']:3d} {rep['seconds']:5.2f}s  "
              f"PSNR {m['psnr']:5.2f} (T {c['telea']['psnr']:5.2f} N {c['ns']['psnr']:5.2f})  "
              f"SSIM {m['ssim']:.3f} (T {c['telea']['ssim']:.3f})  "
              f"LF {m['lowfreq_psnr']:5.2f} (T {c['telea']['lowfreq_psnr']:5.2f})  "
              f"detail {m['detail_ratio']:.2f} (T {c['telea']['detail_ratio']:.2f} N {c['ns']['detail_ratio']:.2f})")
    if not rows:
        return
    ok_detail = sum(0.8 <= r["ours"]["detail_ratio"] <= 1.2 for r in rows)
    ok_lf = sum(r["ours"]["lowfreq_psnr"] >= r["telea"]["lowfreq_psnr"] - 1.0 for r in rows)
    mean = lambda k, who: np.mean([r[who][k] for r in rows])
    print(f"\n{len(rows)} cases, method {args.method}")
    print(f"detail ratio in [0.8, 1.2]: {ok_detail}/{len(rows)}   "
          f"low-freq PSNR >= TELEA - 1 dB: {ok_lf}/{len(rows)}")
    for k in ("psnr", "ssim", "lowfreq_psnr", "detail_ratio"):
        print(f"mean {k:13s} ours {mean(k, 'ours'):7.3f}  TELEA {mean(k, 'telea'):7.3f}  NS {mean(k, 'ns'):7.3f}")
    print(f"mean seconds (ours, in-process) {np.mean([r['seconds'] for r in rows]):.3f}")
    with open(os.path.join(tmp, "results.json"), "w") as f:
        json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Contact sheet: the seven ../shared/data/inpaint/criminisi pairs filled by scantex inpaint
beside cv2.inpaint (TELEA and NS, radius 5). Writes docs/images/inpaint_criminisi.jpg.

    cargo build --release
    python3 benches/inpaint_criminisi.py [--method fast|paper]
"""
import argparse
import os
import subprocess
import tempfile
import time

import cv2
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DATA = os.path.join(ROOT, "..", "shared", "data", "inpaint", "criminisi")
BIN = os.path.join(ROOT, "target", "release", "scantex")


def label(img, text):
    out = img.copy()
    cv2.putText(out, text, (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(out, text, (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--method", default="fast")
    ap.add_argument("--out", default=os.path.join(ROOT, "docs", "images", "inpaint_criminisi.jpg"))
    args = ap.parse_args()
    tmp = tempfile.mkdtemp()
    rows = []
    for k in range(1, 8):
        img = cv2.imread(os.path.join(DATA, f"image{k}.jpg"))
        m = cv2.imread(os.path.join(DATA, f"mask{k}.jpg"), 0)
        # mask4 is stored at 3/5 of its image's size (the data README).
        m = cv2.resize(m, (img.shape[1], img.shape[0]), interpolation=cv2.INTER_NEAREST)
        m = (m > 127).astype(np.uint8)
        ip, mp, op = (os.path.join(tmp, f"{n}{k}.png") for n in ("in", "mask", "out"))
        cv2.imwrite(ip, img)
        cv2.imwrite(mp, m * 255)
        t = time.time()
        subprocess.run([BIN, "inpaint", ip, "--mask", mp, "-o", op, "--method", args.method], check=True,
                       capture_output=True)
        secs = time.time() - t
        ours = cv2.imread(op)
        shown = img.copy()
        shown[m > 0] = (0, 0, 255)
        tiles = [label(shown, f"{k}: input + mask ({100 * m.mean():.0f}%)"),
                 label(ours, f"scantex {args.method} {secs:.1f} s"),
                 label(cv2.inpaint(img, m, 5, cv2.INPAINT_TELEA), "OpenCV TELEA"),
                 label(cv2.inpaint(img, m, 5, cv2.INPAINT_NS), "OpenCV NS")]
        # Common height 240 per row.
        tiles = [cv2.resize(t_, (int(t_.shape[1] * 240 / t_.shape[0]), 240), interpolation=cv2.INTER_AREA)
                 for t_ in tiles]
        rows.append(np.hstack(tiles))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 4), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    cv2.imwrite(args.out, np.vstack(rows), [cv2.IMWRITE_JPEG_QUALITY, 80])
    print("wrote", args.out)


if __name__ == "__main__":
    main()

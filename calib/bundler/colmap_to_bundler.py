"""Writes a COLMAP text model as a Bundler v0.3 file with its image list, in Bundler's
conventions: camera `f k1 k2`, then R (rows) and t of P = R X + t with the camera looking
down -z and y up, i.e. COLMAP's R and t with their second and third rows negated. Only
cameras Bundler can hold are converted: one focal length, principal point at the image
centre, radial terms only (SIMPLE_PINHOLE, SIMPLE_RADIAL, RADIAL). Points are not written.

Usage: python3 calib/bundler/colmap_to_bundler.py samples/torus/sparse/0 calib/bundler/torus.out
(writes torus.out and torus.out.list.txt)
"""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from colmap_text import quat_to_matrix, read_cameras, read_images  # noqa: E402


def main(model, out):
    cams = read_cameras(model)
    images = read_images(model)
    body, names = [], []
    for _, p, cid, name in images:
        model_name, w, h, q = cams[cid]
        f, cx, cy = q[0], q[1], q[2]
        k1 = q[3] if model_name in ("SIMPLE_RADIAL", "RADIAL") else 0.0
        k2 = q[4] if model_name == "RADIAL" else 0.0
        if model_name not in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL") or (cx, cy) != (w / 2, h / 2):
            sys.exit(f"camera {cid}: {model_name} with principal point ({cx}, {cy}) has no Bundler form")
        r = quat_to_matrix(*p[:4])
        tr = p[4:7]
        sign = [1, -1, -1]
        body.append(f"{f!r} {k1!r} {k2!r}")
        for i in range(3):
            body.append(" ".join(repr(sign[i] * v) for v in r[i]))
        body.append(" ".join(repr(sign[i] * tr[i]) for i in range(3)))
        names.append(f"images/{name}")
    with open(out, "w") as fo:
        fo.write("# Bundle file v0.3\n")
        fo.write(f"{len(names)} 0\n")
        fo.write("\n".join(body) + "\n")
    with open(out + ".list.txt", "w") as fo:
        fo.write("\n".join(names) + "\n")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])

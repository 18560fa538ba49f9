"""Writes a COLMAP text model as a VisualSFM NVM_V3 file, in VisualSFM's conventions: one
focal length, the principal point at the image centre, the quaternion of the world-to-camera
rotation, the camera centre, and one *measurement* distortion r on normalised coordinates
(the ideal point is u = d (1 + r |d|^2) of the measured point d, the inverse of COLMAP's
direction).

Pinhole cameras convert exactly (r = 0). NVM's distortion is not COLMAP's: for a
SIMPLE_RADIAL k, COLMAP's own exporter writes r = -k, right to first order; this script fits r
by least squares over the image's pixels instead and prints, per camera, the largest
disagreement of both in pixels (on the bundled sample, whose lenses are strong, 0.6 to 4.5 px
for r = -k and 0.2 to 1.8 px fitted: not exact, hence the undistorted sample below). Only
cameras NVM can hold are converted: one focal length, the principal point at the centre,
SIMPLE_PINHOLE, PINHOLE with fx = fy, or SIMPLE_RADIAL. Points are not written.

Usage (the undistorted sample of calib/undistorted/make.py, exactly):
    python3 calib/nvm/colmap_to_nvm.py calib/undistorted/torus calib/nvm/torus.nvm
"""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from colmap_text import quat_to_matrix, read_cameras, read_images  # noqa: E402


def undistort(k, d):
    """COLMAP's SIMPLE_RADIAL: the ideal radius u with u (1 + k u^2) = d (Newton)."""
    u = d
    for _ in range(50):
        u -= (u * (1 + k * u * u) - d) / (1 + 3 * k * u * u)
    return u


def fit(k, f, w, h):
    """The r of u = d (1 + r d^2) closest to COLMAP's k over a grid of the image's pixels,
    and the largest disagreement in pixels for COLMAP's r = -k and for the fit."""
    radii = []
    for j in range(0, h + 1, 8):
        for i in range(0, w + 1, 8):
            radii.append(((i - w / 2) ** 2 + (j - h / 2) ** 2) ** 0.5 / f)
    us = [undistort(k, d) for d in radii]
    # Least squares on u: d (1 + r d^2) - u = 0 is linear in r.
    r = sum(d ** 3 * (u - d) for d, u in zip(radii, us)) / sum(d ** 6 for d in radii)

    def worst(r):
        # Pixels between the measured radius d and where the NVM camera images COLMAP's ray.
        return max(abs(d - dn) * f for d, u in zip(radii, us)
                   for dn in [newton_nvm(r, u, d)])

    return r, worst(-k), worst(r)


def newton_nvm(r, u, d0):
    """The measured radius d of NVM's camera for the ideal radius u."""
    d = d0
    for _ in range(50):
        d -= (d * (1 + r * d * d) - u) / (1 + 3 * r * d * d)
    return d


def main(model, out):
    cams = read_cameras(model)
    lines = []
    for _, p, cid, name in read_images(model):
        model_name, w, h, q = cams[cid]
        if model_name == "PINHOLE" and q[0] == q[1]:
            q = [q[0], q[2], q[3]]
            model_name = "SIMPLE_PINHOLE"
        f, cx, cy = q[0], q[1], q[2]
        if model_name not in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL") or (cx, cy) != (w / 2, h / 2):
            sys.exit(f"camera {cid}: {model_name} with principal point ({cx}, {cy}) has no NVM form")
        r = 0.0
        if model_name == "SIMPLE_RADIAL":
            r, colmap_px, fit_px = fit(q[3], f, w, h)
            print(f"{name}: k {q[3]:.5f} -> r {r:.5f}: {colmap_px:.3f} px with r = -k, "
                  f"{fit_px:.4f} px fitted", file=sys.stderr)
        qw, qx, qy, qz, tx, ty, tz = p
        # Camera centre C = -R^T t.
        rm = quat_to_matrix(qw, qx, qy, qz)
        c = [-sum(rm[i][j] * (tx, ty, tz)[i] for i in range(3)) for j in range(3)]
        vals = [f, qw, qx, qy, qz, *c, r]
        lines.append(f"images/{name}\t" + " ".join(repr(v) for v in vals) + " 0")
    with open(out, "w") as fo:
        fo.write("NVM_V3\n\n")
        fo.write(f"{len(lines)}\n")
        fo.write("\n".join(lines) + "\n\n0\n\n0\n")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])

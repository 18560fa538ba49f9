"""Reading a COLMAP text model (cameras.txt, images.txt) for the converters in calib/*/."""


def read_cameras(model):
    """{camera id: (model name, width, height, [params])}"""
    cams = {}
    for line in open(f"{model}/cameras.txt"):
        if line.startswith("#") or not line.strip():
            continue
        t = line.split()
        cams[t[0]] = (t[1], int(t[2]), int(t[3]), [float(v) for v in t[4:]])
    return cams


def read_images(model):
    """[(image id, [qw, qx, qy, qz, tx, ty, tz], camera id, name)] in id order."""
    lines = [l for l in open(f"{model}/images.txt") if not l.startswith("#")]
    images = []
    for k in range(0, len(lines) - 1, 2):
        t = lines[k].split()
        if t:
            images.append((int(t[0]), [float(v) for v in t[1:8]], t[8], t[9]))
    images.sort()
    return images


def quat_to_matrix(w, x, y, z):
    """The rotation matrix (rows) of COLMAP's world-to-camera quaternion."""
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]

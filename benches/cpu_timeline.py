#!/usr/bin/env python3
"""Cores in use per stage of one `scantex texture` run (issue 23): samples the process's CPU
time (utime + stime from /proc) every 0.1 s and averages it over each stage's span, taken
from `report.json` (atlas and binding run side by side: their span ends with the later of
the two; the time before the first stage, loading, is its own line). A stage near the
machine's core count cannot gain from running beside another; one well below it has
serial work.

Usage: python3 benches/cpu_timeline.py SCENE [SCANTEX_BINARY] [-- extra texture arguments]

Linux only (reads /proc). Writes the texture to a temporary directory.
"""
import json
import os
import subprocess
import sys
import tempfile
import time


def cpu_seconds(pid):
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    # utime and stime are fields 14 and 15 (1-based), 12 and 13 after the name.
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main():
    args = sys.argv[1:]
    extra = []
    if "--" in args:
        i = args.index("--")
        args, extra = args[:i], args[i + 1 :]
    if not args:
        sys.exit(__doc__)
    scene = args[0]
    binary = args[1] if len(args) > 1 else "target/release/scantex"
    with tempfile.TemporaryDirectory() as out:
        t0 = time.monotonic()
        p = subprocess.Popen([binary, "texture", scene, "-o", out, "-q", *extra])
        samples = []
        while p.poll() is None:
            try:
                samples.append((time.monotonic() - t0, cpu_seconds(p.pid)))
            except (FileNotFoundError, ProcessLookupError, IndexError):
                break
            time.sleep(0.1)
        wall = time.monotonic() - t0
        if p.wait() != 0:
            sys.exit(f"scantex exited with {p.returncode}")
        report = json.load(open(os.path.join(out, "report.json")))
    stages = report["stages"]
    spans = []
    # The report's time is the pipeline's, which ends as the process does; loading the
    # scene is what comes before it.
    side = [s["seconds"] for s in stages if s["stage"] in ("atlas", "bind")]
    start = max(0.0, wall - report["seconds"])
    spans.append(("load", 0.0, start))
    t = start
    if side:
        spans.append(("atlas beside bind", t, t + max(side)))
        t += max(side)
    for s in stages:
        if s["stage"] in ("atlas", "bind"):
            continue
        name = s["stage"] + (f" (tile {s['tile']})" if s.get("tile") else "")
        spans.append((name, t, t + s["seconds"]))
        t += s["seconds"]
    print(f"{scene}: {wall:.1f} s wall, {samples[-1][1] if samples else 0:.1f} CPU s sampled")
    print(f"{'stage':24s} {'from':>6s} {'to':>6s}  cores")
    for name, a, b in spans:
        inside = [(tt, c) for tt, c in samples if a <= tt <= b]
        if len(inside) < 2:
            print(f"{name:24s} {a:6.1f} {b:6.1f}  (under two samples)")
            continue
        (ta, ca), (tb, cb) = inside[0], inside[-1]
        cores = (cb - ca) / (tb - ta) if tb > ta else 0.0
        print(f"{name:24s} {a:6.1f} {b:6.1f}  {cores:5.2f}")


if __name__ == "__main__":
    main()

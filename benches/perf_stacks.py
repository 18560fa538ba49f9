#!/usr/bin/env python3
"""Where one function's time goes inside a scantex run, from `perf` call stacks (issue 23).

    python3 benches/perf_stacks.py BIN [BIN...] --scene SCENE [--within build_sources]
                                   [--parts a,b,c] [--rounds N]

Runs `BIN texture SCENE -o <tmp> -q` under `perf record --call-graph dwarf` (the release
profile keeps line tables, so inlined functions have names), then counts the samples whose
stack holds `--within`, and of those the ones whose frames below it hold each of `--parts`
(the first that matches; `other` for none). Samples are of CPU time (`cpu-clock`) at 1999
Hz, so counts divided by 1999 are CPU seconds. This machine's speed drifts from hour to
hour: compare builds by their shares of the run's samples, alternating them (`--rounds`),
not by seconds.
Needs `perf` (Debian: linux-perf).
"""
import argparse
import os
import subprocess
import tempfile

PARTS = "Pca::fit,Pca::project,source_vector|context|push_texel,valid_source,vector_key|wrapping_mul|HashSet,build_tree,sort_unstable"


def count(script, within, parts):
    total = hit = 0
    by = dict.fromkeys([p for p in parts] + ["other"], 0)
    stack = []

    def flush():
        nonlocal total, hit
        if not stack:
            return
        total += 1
        below = []
        for frame in stack:
            if within in frame:
                hit += 1
                text = " ".join(below)
                for p in parts:
                    if any(alt in text for alt in p.split("|")):
                        by[p] += 1
                        break
                else:
                    by["other"] += 1
                return
            below.append(frame)

    for line in script.splitlines():
        if not line.strip():
            flush()
            stack.clear()
            continue
        fields = line.strip().split(None, 1)
        stack.append(fields[-1])
    flush()
    return total, hit, by


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("bin", nargs="+", help="scantex binaries, run in turn each round")
    ap.add_argument("--scene", required=True)
    ap.add_argument("--within", default="build_sources")
    ap.add_argument("--parts", default=PARTS, help="comma-separated; `a|b` counts either")
    ap.add_argument("--rounds", type=int, default=1)
    o = ap.parse_args()
    parts = o.parts.split(",")
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(o.rounds):
            for b in o.bin:
                data = os.path.join(tmp, "perf.data")
                subprocess.run(
                    ["perf", "record", "-q", "-e", "cpu-clock", "-F", "1999", "--call-graph", "dwarf,16384", "-o", data,
                     b, "texture", o.scene, "-o", os.path.join(tmp, "out"), "-q"],
                    check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                script = subprocess.run(["perf", "script", "-i", data, "-F", "ip,sym"],
                                        check=True, capture_output=True, text=True).stdout
                total, hit, by = count(script, o.within, parts)
                print(f"round {r + 1} {b}: {total} samples, {hit} in {o.within} "
                      f"({100 * hit / max(total, 1):.1f}%): "
                      + ", ".join(f"{k} {v}" for k, v in by.items()))


if __name__ == "__main__":
    main()

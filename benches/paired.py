#!/usr/bin/env python3
"""Two scantex builds on one scene at the same time, one thread each (issue 23).

    python3 benches/paired.py SCENE BIN_A BIN_B [--rounds N] [--args "..."] [--args-b "..."]

This machine's speed drifts by 20-40% from one hour to the next, more than most changes are
worth, so runs made one after the other compare hours as much as builds. Here both builds run
side by side, each on one core (`--threads 1`), so whatever the machine does to one it does to
the other; each round prints, per build, wall and CPU seconds, peak memory, the stages'
seconds from `report.json` and the merge's sampling CPU seconds, and whether `model.png` came
out the same bytes. With BIN_A the same binary as BIN_B it measures the method's own spread,
or with `--args-b` what an option costs.
One thread per build measures the work, not how it spreads over cores: a change to
parallelism needs runs with every core.
"""
import argparse
import json
import os
import shlex
import subprocess
import tempfile


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene")
    ap.add_argument("a")
    ap.add_argument("b")
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--args", default="", help="extra arguments for both runs of `scantex texture`")
    ap.add_argument("--args-b", default="", help="extra arguments for build B's runs only")
    opts = ap.parse_args()
    extra = {"A": shlex.split(opts.args), "B": shlex.split(opts.args) + shlex.split(opts.args_b)}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(opts.rounds):
            procs = []
            for name, binary in (("A", opts.a), ("B", opts.b)):
                out = os.path.join(tmp, f"{name}{r}")
                timing = os.path.join(tmp, f"{name}{r}.time")
                cmd = ["/usr/bin/time", "-f", "%e %U %S %M", "-o", timing, binary, "texture",
                       opts.scene, "-o", out, "--threads", "1", "-q"] + extra[name]
                procs.append((name, out, timing, subprocess.Popen(cmd, stdout=subprocess.DEVNULL,
                                                                  stderr=subprocess.PIPE)))
            rows = []
            for name, out, timing, p in procs:
                _, err = p.communicate()
                if p.returncode != 0:
                    raise SystemExit(f"build {name} failed: {err.decode(errors='replace')[-2000:]}")
                wall, user, sys_, peak = open(timing).read().split()[-4:]
                rep = json.load(open(os.path.join(out, "report.json")))
                stages = {s["stage"]: s["seconds"] for s in rep["stages"]}
                sampling = sum(pg["merging"]["cpu_seconds_sampling"] for pg in rep["pages"]
                               if pg.get("merging"))
                rows.append((name, float(wall), float(user), float(sys_), int(peak) / 1024,
                             stages, sampling))
            same = subprocess.run(["cmp", "-s", os.path.join(tmp, f"A{r}", "model.png"),
                                   os.path.join(tmp, f"B{r}", "model.png")]).returncode == 0
            print(f"round {r + 1}: model.png {'the same bytes' if same else 'differs'}")
            names = list(rows[0][5])
            print("| build | wall s | user s | sys s | peak MiB | sampling CPU s | "
                  + " | ".join(names) + " |")
            print("|---" * (6 + len(names)) + "|")
            for name, wall, user, sys_, peak, stages, sampling in rows:
                print(f"| {name} | {wall:.1f} | {user:.1f} | {sys_:.1f} | {peak:,.0f} | {sampling:.2f} | "
                      + " | ".join(f"{stages.get(n, 0):.2f}" for n in names) + " |")


if __name__ == "__main__":
    main()

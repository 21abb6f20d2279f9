#!/usr/bin/env python3
"""City-scale cost of `coid run`: instances, wall time, instances per
second, real-time factor, peak RSS and the networks' arithmetic (GFLOP
as the run counts it from the products' shapes, and GFLOP/s of wall
time, to hold against the matcher bench's peak), for one scenario at several
penetration rates and thread counts (docs/city-scale.md).

By default the scenario is the generated dense town of
`sumo_nets/checks/make_foreign.sh` (`densetown`, built into OUT/nets on
first use) run for 300 s at penetration 0.1, 0.3, 0.5 and 1.0 with 1 and 2
threads, every method, every pose-noise level: the issue-21 benchmark.

    benches/scale.py                                  # the table above
    benches/scale.py --pens 0.3 --threads 2 --end-s 400 800 \\
        --config /tmp/real/bs/coid.toml                # memory by run length
    benches/scale.py --pens 1.0 --threads 2 \\
        --variant pairwise: --variant map:'[matching]\\nmulti_vehicle = "map"' \\
        --variant 'range 50 m:+comm_range_m = 50.0'    # modes and links

A variant is `NAME:TOML`: TOML is appended to the config; a TOML that
starts with `+` goes into `[connected]` instead. Every run writes its
results folder under OUT (default results/scale); a `summary.csv` row of
`ours` (aligned fusion) at each level is printed beside the cost.
Only the Python standard library; peak RSS is the run's own (getrusage
of a child process that waits for exactly one `coid`).
"""

import argparse
import csv
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def coid_binary() -> Path:
    target = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    exe = target / "release" / "coid"
    if not exe.is_file():
        sys.exit(f"error: {exe} not found: build it first (./coid --help builds it)")
    return exe


def measured(argv: list[str]) -> dict:
    """Runs argv in a fresh Python process that reports the child's wall
    time and peak RSS (ru_maxrss of its only child)."""
    probe = (
        "import json, resource, subprocess, sys, time\n"
        "t = time.monotonic()\n"
        "p = subprocess.run(sys.argv[1:], capture_output=True, text=True)\n"
        "wall = time.monotonic() - t\n"
        "rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss\n"
        "print(json.dumps({'rc': p.returncode, 'wall_s': wall, 'peak_rss_mb': rss / 1024,"
        " 'stderr': p.stderr}))\n"
    )
    out = subprocess.run([sys.executable, "-c", probe, *argv], capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit(f"error: the measuring process failed: {out.stderr}")
    return json.loads(out.stdout)


def config_text(base: Path, pen: float, end_s: float, toml: str) -> str:
    text = base.read_text()
    text = re.sub(r"(?m)^end_s\s*=.*$", f"end_s = {end_s}", text)
    text = re.sub(r"(?m)^(sumocfg\s*=\s*)\"(.*)\"", lambda m: f'{m.group(1)}"{(base.parent / m.group(2)).resolve()}"', text)
    if re.search(r"(?m)^penetration\s*=", text):
        text = re.sub(r"(?m)^penetration\s*=.*$", f"penetration = {pen}", text)
    else:
        text += f"\n[connected]\npenetration = {pen}\n"
    if toml.startswith("+"):
        text = re.sub(r"(?m)^(penetration\s*=.*)$", lambda m: m.group(1) + "\n" + toml[1:], text)
    elif toml:
        text += "\n" + toml + "\n"
    return text


def ours_at_gps(results: Path) -> dict:
    """`ours`, aligned fusion, at 1.2 m pose noise, from summary.csv."""
    for r in csv.DictReader(open(results / "summary.csv")):
        if r["method"] == "ours" and r["fusion"] == "aligned" and r["pose_noise"] == "gps":
            return {k: float(r[k]) for k in
                    ["f1", "object_f1", "n_ego_objects", "de_single_per_ego_m", "de_fused_all_views_m"]}
    return {}


def quality(o: dict, ref: dict | None) -> str:
    """F1 and object F1 of `ours` at 1.2 m, and its all-view fused DE over
    every (ego, object) of the reference run (the first variant): an
    (ego, object) this run has no instance for keeps its single-vehicle
    error, which is the same in both runs (same seeds, same detections)."""
    if not o:
        return "| | |"
    n, single, de = o["n_ego_objects"], o["de_single_per_ego_m"], o["de_fused_all_views_m"]
    if ref and ref["n_ego_objects"] >= n:
        missing = ref["n_ego_objects"] * ref["de_single_per_ego_m"] - n * single
        de = (n * de + missing) / ref["n_ego_objects"]
        single = ref["de_single_per_ego_m"]
    return f"{o['f1']:.3f} / {o['object_f1']:.3f} | {single:.3f} -> {de:.3f} m |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", type=Path, help="a coid.toml (default: OUT/nets/densetown/coid.toml)")
    ap.add_argument("--pens", type=float, nargs="+", default=[0.1, 0.3, 0.5, 1.0])
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2],
                    help="threads of each run; 0: leave --threads out (a build from before it existed)")
    ap.add_argument("--end-s", type=float, nargs="+", default=[300.0])
    ap.add_argument("--variant", action="append", default=[], help="NAME:TOML (see above)")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "scale")
    a = ap.parse_args()
    exe = coid_binary()
    a.out.mkdir(parents=True, exist_ok=True)
    config = a.config
    if config is None:
        nets = a.out / "nets"
        config = nets / "densetown" / "coid.toml"
        if not config.is_file():
            subprocess.run([str(ROOT / "sumo_nets/checks/make_foreign.sh"), str(nets)], check=True)
    variants = [v.split(":", 1) for v in a.variant] or [["default", ""]]
    print(f"scenario: {config}")
    print("| variant | penetration | end_s | threads | instances | wall s | instances/s | real-time factor"
          " | peak RSS MB | networks GFLOP | GFLOP/s | ours @1.2 m: F1 / object F1 | DE single -> all views |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---|")
    reference: dict = {}
    for name, toml in variants:
        for pen in a.pens:
            for end_s in a.end_s:
                cfg = a.out / f"{name.replace(' ', '_')}-p{pen}-e{end_s:g}.toml"
                cfg.write_text(config_text(config, pen, end_s, toml.replace("\\n", "\n")))
                for threads in a.threads:
                    res = a.out / f"{cfg.stem}-t{threads}"
                    flag = ["--threads", str(threads)] if threads else []
                    m = measured([str(exe), "run", "-q", "--force", *flag,
                                  "--config", str(cfg), "--out", str(res)])
                    if m["rc"] != 0:
                        sys.exit(f"error: coid run failed ({cfg}): {m['stderr']}")
                    n = int(re.search(r"(\d+) instances", m["stderr"]).group(1))
                    wall = m["wall_s"]
                    # The networks' arithmetic as the run counts it (a build
                    # from before the count prints none).
                    g = re.search(r"networks ([\d.]+) GFLOP", m["stderr"])
                    flops = f"{float(g.group(1)):.0f} | {float(g.group(1)) / wall:.1f}" if g else "- | -"
                    o = ours_at_gps(res) if n else {}
                    ref = reference.setdefault((pen, end_s), o)
                    print(f"| {name} | {pen} | {end_s:g} | {threads} | {n} | {wall:.1f} | {n / wall:.0f} | "
                          f"{end_s / wall:.1f} | {m['peak_rss_mb']:.0f} | {flops} | {quality(o, ref)}", flush=True)


if __name__ == "__main__":
    main()

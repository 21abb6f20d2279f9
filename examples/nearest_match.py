"""A matcher written outside coid: greedy nearest neighbours in the first
vehicle's frame, from the GPS-reported poses alone, through the coid_sim
package (pip install coid-sim).

    python examples/nearest_match.py                 # the default test runs, exported here first
    python examples/nearest_match.py results/my-export --out my-matches.parquet

Reads a dataset (a folder `coid export` or `coid_sim.export` wrote, or
one converted from elsewhere; without one, the default configuration's
validation and test runs, exported into results/default-export once), matches every
instance of the split, prints the precision, recall and F1 its rule
implies, counted as coid counts them (per run, pooled over the run's
instances; then the mean over runs), and then has coid score the same
matches beside its built-in methods (`coid_sim.score`, the tables of
`coid score`).

The rule: move the second vehicle's nodes into the first vehicle's body
frame with both reported poses; take pairs of the same class in order of
distance, each node at most once, while the distance is below --gate
metres. A pair's probability is exp(-d^2 / (2 s^2)), s^2 = 1 m^2 of
detection noise plus twice the level's reported GPS variance.
"""

import argparse
import sys
from pathlib import Path

import numpy as np
import polars as pl

import coid_sim


def to_first_frame(xy, first, second):
    """Second-vehicle body-frame points into the first vehicle's body frame."""
    (x1, y1, h1), (x2, y2, h2) = first, second
    c2, s2 = np.cos(h2), np.sin(h2)
    world = np.stack([x2 + c2 * xy[:, 0] - s2 * xy[:, 1], y2 + s2 * xy[:, 0] + c2 * xy[:, 1]], 1)
    dx, dy = world[:, 0] - x1, world[:, 1] - y1
    c1, s1 = np.cos(h1), np.sin(h1)
    return np.stack([c1 * dx + s1 * dy, -s1 * dx + c1 * dy], 1)


def match(inst, level, gate_m):
    """The rule, on one instance at one level: [(a, b, probability)]."""
    a_xy = inst.first.xy_m
    b_xy = to_first_frame(inst.second.xy_m, *level.reported)
    d = np.linalg.norm(a_xy[:, None, :] - b_xy[None, :, :], axis=2)
    same = inst.first.classes[:, None] == inst.second.classes[None, :]
    d = np.where(same, d, np.inf)
    s2 = 1.0 + 2.0 * level.position_sigma_m**2
    used_a, used_b, out = set(), set(), []
    for k in np.argsort(d, axis=None, kind="stable"):
        a, b = divmod(int(k), d.shape[1])
        if d[a, b] >= gate_m:
            break
        if a in used_a or b in used_b:
            continue
        used_a.add(a)
        used_b.add(b)
        out.append((a, b, float(np.exp(-d[a, b] ** 2 / (2.0 * s2)))))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path, nargs="?", help="a dataset folder [default: export the default test runs]")
    ap.add_argument("--out", type=Path, default=Path("matches.parquet"), help="the matches file written")
    ap.add_argument("--split", default="test", choices=["validation", "test"])
    ap.add_argument("--gate", type=float, default=3.0, help="largest distance matched (m)")
    ap.add_argument("--score-out", type=Path, help="coid score's results folder [default: results/<dataset>-score]")
    args = ap.parse_args()

    if args.dataset is None:
        # The default configuration's runs, exported once.
        out = Path("results/default-export")
        dataset = coid_sim.Dataset(out) if out.exists() else coid_sim.export(splits=["validation", "test"], out=out)
    else:
        dataset = coid_sim.Dataset(args.dataset)
    rows, per_run, n_instances = [], {}, 0
    for inst in dataset.instances(args.split):
        n_instances += 1
        for level in inst.levels:
            made = match(inst, level, args.gate)
            true = {(int(a), int(b)) for a, b in inst.true_pairs}
            counts = per_run.setdefault((inst.run, level.label), [0, 0, 0])
            counts[0] += len(made)
            counts[1] += sum((a, b) in true for a, b, _ in made)
            counts[2] += len(true)
            rows += [(inst.run, inst.instance, level.label, a, b, p) for a, b, p in made]
    if not per_run:
        sys.exit(f"{dataset.path} holds no {args.split} instance")
    matches = pl.DataFrame(
        rows,
        schema={"run": pl.UInt64, "instance": pl.UInt64, "pose_noise": pl.String,
                "a": pl.UInt64, "b": pl.UInt64, "probability": pl.Float64},
        orient="row",
    )
    matches.write_parquet(args.out)

    # What the rule implies, counted as coid counts it: per run, then the
    # mean over runs (a run with nothing identified has no precision).
    runs = dataset.runs.filter(pl.col("split") == args.split)["run"].to_list()
    print(f"nearest_match: {matches.height} matches on {n_instances} instances x {len(dataset.levels)} levels "
          f"of {len(runs)} {args.split} runs; wrote {args.out}")
    for label, _ in dataset.levels:
        p, r, f = [], [], []
        for run in runs:
            identified, correct, truth = per_run.get((run, label), [0, 0, 0])
            if identified:
                p.append(correct / identified)
            if truth:
                r.append(correct / truth)
            if identified + truth:
                f.append(2 * correct / (identified + truth))
        print(f"{label}: precision {np.mean(p):.6f} recall {np.mean(r):.6f} f1 {np.mean(f):.6f} over {len(runs)} runs")

    scored = coid_sim.score(matches, dataset=dataset, split=args.split, out=args.score_out, force=True, quiet=True)
    table = scored.frame("table1b").filter(pl.col("pose_noise") == "gps")
    print(f"coid score (gps): {scored.out}")
    for row in table.iter_rows(named=True):
        print(f"  {row['method']:<20} precision {row['precision']:.3f} recall {row['recall']:.3f} f1 {row['f1']:.3f}")


if __name__ == "__main__":
    main()

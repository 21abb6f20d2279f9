"""A matcher written outside coid: greedy nearest neighbours in the first
vehicle's frame, from the GPS-reported poses alone.

    coid export --splits test --out results/my-export
    python examples/nearest_match.py results/my-export --out my-matches.parquet
    coid score --matches my-matches.parquet --export results/my-export --out results/my-score

Reads an export (schema: the export's schema.md), writes a matches file
for `coid score`, and prints the precision, recall and F1 its rule
implies on the split, counted as coid counts them: per run, pooled over
the run's instances; then the mean over runs. Needs only polars and
numpy.

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


def to_first_frame(xy, first, second):
    """Second-vehicle body-frame points into the first vehicle's body frame."""
    (x1, y1, h1), (x2, y2, h2) = first, second
    c2, s2 = np.cos(h2), np.sin(h2)
    world = np.stack([x2 + c2 * xy[:, 0] - s2 * xy[:, 1], y2 + s2 * xy[:, 0] + c2 * xy[:, 1]], 1)
    dx, dy = world[:, 0] - x1, world[:, 1] - y1
    c1, s1 = np.cos(h1), np.sin(h1)
    return np.stack([c1 * dx + s1 * dy, -s1 * dx + c1 * dy], 1)


def match(first_nodes, second_nodes, inst, gate_m):
    """The rule, on one instance at one level: [(a, b, probability)]."""
    a_xy = first_nodes.select("x_m", "y_m").to_numpy()
    b_xy = to_first_frame(
        second_nodes.select("x_m", "y_m").to_numpy(),
        (inst["first_x_m"], inst["first_y_m"], inst["first_heading_rad"]),
        (inst["second_x_m"], inst["second_y_m"], inst["second_heading_rad"]),
    )
    d = np.linalg.norm(a_xy[:, None, :] - b_xy[None, :, :], axis=2)
    same = first_nodes["class"].to_numpy()[:, None] == second_nodes["class"].to_numpy()[None, :]
    d = np.where(same, d, np.inf)
    s2 = 1.0 + 2.0 * inst["position_sigma_m"] ** 2
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
    ap.add_argument("export", type=Path, help="a folder written by coid export")
    ap.add_argument("--out", type=Path, default=Path("matches.parquet"))
    ap.add_argument("--split", default="test", choices=["train", "validation", "test"])
    ap.add_argument("--gate", type=float, default=3.0, help="largest distance matched (m)")
    args = ap.parse_args()

    runs = pl.read_parquet(args.export / "runs.parquet").filter(pl.col("split") == args.split)
    if runs.height == 0:
        sys.exit(f"{args.export} holds no {args.split} run")
    keep = pl.col("run").is_in(runs["run"].to_list())
    instances = pl.read_parquet(args.export / "instances.parquet").filter(keep)
    nodes = pl.read_parquet(args.export / "nodes.parquet").filter(keep).sort("run", "instance", "side", "node")
    truth = pl.read_parquet(args.export / "true_pairs.parquet").filter(keep)

    by_vehicle = nodes.partition_by(["run", "instance", "side"], as_dict=True)
    rows = []
    for inst in instances.iter_rows(named=True):
        key = (inst["run"], inst["instance"])
        first, second = by_vehicle[key + (0,)], by_vehicle[key + (1,)]
        for a, b, p in match(first, second, inst, args.gate):
            rows.append((inst["run"], inst["instance"], inst["pose_noise"], a, b, p))
    matches = pl.DataFrame(
        rows,
        schema={"run": pl.UInt64, "instance": pl.UInt64, "pose_noise": pl.String,
                "a": pl.UInt64, "b": pl.UInt64, "probability": pl.Float64},
        orient="row",
    )
    matches.write_parquet(args.out)

    # What the rule implies, counted as coid counts it.
    true_set = truth.with_columns(pl.lit(True).alias("correct"))
    judged = matches.join(true_set, on=["run", "instance", "a", "b"], how="left")
    judged = judged.with_columns(pl.col("correct").fill_null(False))
    per_run = (
        judged.group_by("run", "pose_noise")
        .agg(pl.len().alias("identified"), pl.col("correct").sum().alias("correct"))
    )
    levels = instances.select("pose_noise").unique(maintain_order=True)
    gt = truth.group_by("run").agg(pl.len().alias("ground_truth"))
    counts = (
        runs.select("run").join(levels, how="cross")
        .join(per_run, on=["run", "pose_noise"], how="left")
        .join(gt, on="run", how="left")
        .fill_null(0)
        .with_columns(
            precision=pl.when(pl.col("identified") > 0).then(pl.col("correct") / pl.col("identified")),
            recall=pl.when(pl.col("ground_truth") > 0).then(pl.col("correct") / pl.col("ground_truth")),
            f1=pl.when(pl.col("identified") + pl.col("ground_truth") > 0)
            .then(2 * pl.col("correct") / (pl.col("identified") + pl.col("ground_truth"))),
        )
    )
    table = counts.group_by("pose_noise", maintain_order=True).agg(
        pl.col("precision").mean(), pl.col("recall").mean(), pl.col("f1").mean(), pl.len().alias("n_runs")
    )
    print(f"nearest_match: {matches.height} matches on {instances.height} (instance, level) of "
          f"{runs.height} {args.split} runs; wrote {args.out}")
    for r in table.iter_rows(named=True):
        print(f"{r['pose_noise']}: precision {r['precision']:.6f} recall {r['recall']:.6f} "
              f"f1 {r['f1']:.6f} over {r['n_runs']} runs")


if __name__ == "__main__":
    main()

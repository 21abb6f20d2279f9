"""A small PyTorch Geometric matcher trained on a coid dataset and scored
by coid beside its built-in methods.

    pip install coid-sim torch torch_geometric
    python examples/train_pyg.py                      # the default configuration, exported first
    python examples/train_pyg.py results/my-export    # any dataset with train and test runs

The network: each vehicle's nodes (coid's features: class, colour, size,
appearance where given; and their world positions through the reported
GPS pose) are embedded by an MLP and two rounds of message passing over
the vehicle's Delaunay graph (``GraphConv``); a pair's score is the dot
product of the embeddings minus a learned multiple of the squared world
distance; each first-vehicle node chooses among the second's nodes and
"none" (a learned dustbin score) with a softmax, trained with the
cross-entropy against ``y`` (DGMC's ``PairData``: the partner's index,
or -1 for none). Weights are chosen on the validation runs (the epoch
with the best validation loss); matches are kept where both nodes choose
each other. Then ``coid_sim.score`` scores them on the test runs with the
tables of ``coid score``.
"""

import argparse
import copy
from pathlib import Path

import polars as pl

import coid_sim

try:
    import torch
    from torch import nn
    from torch_geometric.loader import DataLoader
    from torch_geometric.nn import GraphConv
except ImportError as e:  # pragma: no cover - the example needs them
    raise SystemExit(f"this example needs torch and torch_geometric ({e}): pip install torch torch_geometric")


class Matcher(nn.Module):
    def __init__(self, features: int, hidden: int = 64) -> None:
        super().__init__()
        self.embed = nn.Sequential(nn.Linear(features + 2, hidden), nn.ReLU(), nn.Linear(hidden, hidden))
        self.convs = nn.ModuleList([GraphConv(hidden, hidden), GraphConv(hidden, hidden)])
        self.distance_weight = nn.Parameter(torch.tensor(0.5))
        self.dustbin = nn.Parameter(torch.tensor(0.0))

    def nodes(self, x, pos_world, edge_index, centre):
        h = self.embed(torch.cat([x, (pos_world - centre) / 50.0], dim=1))
        for conv in self.convs:
            h = h + torch.relu(conv(h, edge_index))
        return h

    def forward(self, d):
        """Log-probabilities ``[n_s, n_t + 1]`` of one pair (last column: none)."""
        centre = torch.cat([d.pos_world_s, d.pos_world_t]).mean(dim=0)
        hs = self.nodes(d.x_s, d.pos_world_s, d.edge_index_s, centre)
        ht = self.nodes(d.x_t, d.pos_world_t, d.edge_index_t, centre)
        dist2 = torch.cdist(d.pos_world_s, d.pos_world_t) ** 2
        scores = hs @ ht.T / hs.size(1) ** 0.5 - self.distance_weight.abs() * dist2
        none = self.dustbin.expand(scores.size(0), 1)
        return torch.log_softmax(torch.cat([scores, none], dim=1), dim=1)


def loss_of(model, pairs):
    total, n = 0.0, 0
    for d in pairs:
        if d.x_s.size(0) == 0 or d.x_t.size(0) == 0:
            continue
        logp = model(d)
        target = torch.where(d.y >= 0, d.y, torch.full_like(d.y, d.x_t.size(0)))
        total = total + nn.functional.nll_loss(logp, target, reduction="sum")
        n += d.y.size(0)
    return total / max(n, 1)


def mutual_matches(model, d):
    """Pairs whose nodes choose each other, with the first's probability."""
    if d.x_s.size(0) == 0 or d.x_t.size(0) == 0:
        return []
    with torch.no_grad():
        p = model(d).exp()
    best_t = p[:, :-1].argmax(dim=1)
    best_s = p[:, :-1].argmax(dim=0)
    out = []
    for a in range(p.size(0)):
        b = int(best_t[a])
        if p[a, b] > p[a, -1] and int(best_s[b]) == a:
            out.append((a, b, float(p[a, b])))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path, nargs="?", help="a dataset with train, validation and test runs")
    ap.add_argument("--epochs", type=int, default=15)
    ap.add_argument("--level", default="gps", help="the pose-noise level trained and scored")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--score-out", type=Path)
    args = ap.parse_args()
    torch.manual_seed(args.seed)

    if args.dataset is None:
        # The default configuration's runs, exported once.
        out = Path("results/default-export-all")
        dataset = coid_sim.Dataset(out) if out.exists() else coid_sim.export(out=out)
    else:
        dataset = coid_sim.Dataset(args.dataset)
    train = dataset.to_pyg("train", args.level)
    validation = dataset.to_pyg("validation", args.level)
    if not train or not validation:
        raise SystemExit(f"{dataset.path} needs train and validation runs")
    model = Matcher(train[0].x_s.size(1))
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    best, best_loss = None, float("inf")
    for epoch in range(args.epochs):
        model.train()
        for batch in DataLoader(train, batch_size=1, shuffle=True):
            opt.zero_grad()
            loss = loss_of(model, [batch])
            loss.backward()
            opt.step()
        model.eval()
        with torch.no_grad():
            v = float(loss_of(model, validation))
        print(f"epoch {epoch + 1}: validation loss {v:.4f}")
        if v < best_loss:
            best, best_loss = copy.deepcopy(model.state_dict()), v
    model.load_state_dict(best)

    rows = []
    for inst in dataset.instances("test"):
        for a, b, p in mutual_matches(model, inst.to_pyg(args.level)):
            rows.append((inst.run, inst.instance, args.level, a, b, p))
    matches = pl.DataFrame(
        rows,
        schema={"run": pl.UInt64, "instance": pl.UInt64, "pose_noise": pl.String,
                "a": pl.UInt64, "b": pl.UInt64, "probability": pl.Float64},
        orient="row",
    )
    scored = coid_sim.score(matches, dataset=dataset, out=args.score_out, force=True, quiet=True)
    table = scored.frame("table1b").filter(pl.col("pose_noise") == args.level)
    print(f"coid score ({args.level}, test runs): {scored.out}")
    for row in table.iter_rows(named=True):
        print(f"  {row['method']:<20} precision {row['precision']:.3f} recall {row['recall']:.3f} f1 {row['f1']:.3f}")


if __name__ == "__main__":
    main()

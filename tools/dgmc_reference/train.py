"""Trains the paper's network on a coid dataset's train split with DGMC's
reference code (PyTorch Geometric), the way ``coid train`` trains it, and
writes weights coid runs (``<out>/<method>.bpk``, its loss curve
``<method>_loss.csv``, and with ``--record`` its record).

The recipe is coid's (``configs/default.toml``'s ``[train]``): DGMC's
``loss(S_0) + loss(S_L)`` as the negative log-likelihood of the labels with
dustbins (true pairs, and "no match" for a node without a partner, each
half weighed a half with ``--no-match halves``), the paper's Eq. 12 and 13
on the mean of the samples' ``S_L`` for ``coid``, ``--samples`` dropout
samples per pair, Adam (burn's epsilon, 1e-5) at a warm-up then cosine
learning rate, batches of ``--batch-size`` grouped by size, early stopping
on the validation split's loss with ``--patience``. The network is DGMC's
forward with coid's departures (``check.py``): the paper's psi_1 sizes,
Sinkhorn with a dustbin, dropout after psi_1's first layer; initial weights
are PyTorch Geometric's own. Prints each epoch's losses.
"""

from __future__ import annotations

import argparse
import tomllib
import math
import random
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parent))
from check import graph_of, load_dgmc, one_line_errors  # noqa: E402

BLOCKED = -1.0e4
WARMUP_STEPS = 200


def learning_rate(peak: float, step: int, total: int) -> float:
    """coid's schedule: linear warm-up, then cosine to a twentieth."""
    warmup = max(min(WARMUP_STEPS, total // 10), 1)
    if step < warmup:
        return peak * (step + 1) / warmup
    progress = (step - warmup) / max(total - warmup, 1)
    floor = peak / 20.0
    return floor + 0.5 * (peak - floor) * (1.0 + math.cos(math.pi * min(progress, 1.0)))


def log_dustbin_sinkhorn(s_hat, s_mask, n1, n2, dustbin, iters):
    """Batched log-domain Sinkhorn with a dustbin row and column (coid's
    ``train::sinkhorn::log_sinkhorn``): ``[B, N1 + 1, N2 + 1]``."""
    b, r, c = s_hat.shape
    z = s_hat.masked_fill(~s_mask, BLOCKED)
    bin_ = dustbin.reshape(1, 1, 1)
    top = torch.cat([z, bin_.expand(b, r, 1)], dim=2)
    z = torch.cat([top, bin_.expand(b, 1, c + 1)], dim=1)
    n1f, n2f = n1.to(z.dtype), n2.to(z.dtype)
    norm = -torch.log(n1f + n2f)
    rows = torch.arange(r)[None, :] < n1[:, None]
    cols = torch.arange(c)[None, :] < n2[:, None]
    log_mu = torch.cat([torch.where(rows, norm[:, None], torch.tensor(BLOCKED)), (torch.log(n2f) + norm)[:, None]], dim=1)
    log_nu = torch.cat([torch.where(cols, norm[:, None], torch.tensor(BLOCKED)), (torch.log(n1f) + norm)[:, None]], dim=1)
    u = torch.zeros(b, r + 1, 1)
    v = torch.zeros(b, 1, c + 1)
    for _ in range(iters):
        u = log_mu[:, :, None] - torch.logsumexp(z + v, dim=2, keepdim=True)
        v = log_nu[:, None, :] - torch.logsumexp(z + u, dim=1, keepdim=True)
    return z + u + v - norm[:, None, None]


class Psi1(torch.nn.Module):
    """The paper's psi_1 (see check.py), dropout drawn here."""

    def __init__(self, f, hidden, out, p):
        super().__init__()
        from torch_geometric.nn import SplineConv

        self.conv1 = SplineConv(f, hidden, dim=1, kernel_size=5)
        self.conv2 = SplineConv(hidden, out, dim=1, kernel_size=5)
        self.final = torch.nn.Linear(out, out)
        self.p = p

    def forward(self, x, edge_index, edge_attr, *args):
        h = torch.relu(self.conv1(x, edge_index, edge_attr))
        h = F.dropout(h, self.p, training=self.training)
        h = torch.relu(self.conv2(h, edge_index, edge_attr))
        return self.final(h)


class Net(torch.nn.Module):
    def __init__(self, dgmc_path, cfg):
        super().__init__()
        self.module, DGMC, SplineCNN = load_dgmc(dgmc_path)
        r = cfg["consensus_dim"]
        self.cfg = cfg
        self.psi1 = Psi1(cfg["node_features"], cfg["hidden"], cfg["out"], cfg["dropout_conv"])
        psi2 = SplineCNN(r, r, 1, 2, cat=True, lin=True, dropout=0.0)
        self.dgmc = DGMC(self.psi1, psi2, num_steps=cfg["consensus_steps"])
        self.dustbin = torch.nn.Parameter(torch.tensor([1.0]))
        self.logs = []

        def masked_softmax(src, mask, dim=-1):
            n1 = mask.any(2).sum(1)
            n2 = mask.any(1).sum(1)
            log_p = log_dustbin_sinkhorn(src, mask, n1, n2, self.dustbin, cfg["sinkhorn_iters"])
            self.logs.append(log_p)
            return log_p[:, :-1, :-1].exp().masked_fill(~mask, 0)

        self.module.masked_softmax = masked_softmax

    def forward(self, batch):
        """``[B, N1 + 1, N2 + 1]`` log assignments under S_0 and S_L."""
        self.logs = []
        self.dgmc(*batch)
        return self.logs[0], self.logs[-1]

    def parameters_by_name(self):
        """The parameters in coid's names and layouts."""
        out = {}

        def conv(layer, name):
            w = layer.weight.detach()  # [knots, in, out]
            out[f"{name}.weight"] = w.permute(1, 0, 2).reshape(w.shape[1], -1)
            out[f"{name}.root"] = layer.lin.weight.detach().T
            out[f"{name}.bias"] = layer.bias.detach()

        def linear(layer, name):
            out[f"{name}.weight"] = layer.weight.detach().T
            out[f"{name}.bias"] = layer.bias.detach()

        conv(self.psi1.conv1, "psi1.conv1")
        conv(self.psi1.conv2, "psi1.conv2")
        linear(self.psi1.final, "psi1.last")
        if self.cfg["consensus_steps"] > 0:
            conv(self.dgmc.psi_2.convs[0], "psi2.conv1")
            conv(self.dgmc.psi_2.convs[1], "psi2.conv2")
            linear(self.dgmc.psi_2.final, "psi2.last")
            linear(self.dgmc.mlp[0], "mlp_in")
            linear(self.dgmc.mlp[2], "mlp_out")
        out["dustbin"] = self.dustbin.detach()
        return {k: (list(v.shape), v.contiguous().reshape(-1).tolist()) for k, v in out.items()}


def pairs_of(dataset, split, width, scale):
    """Each instance of ``split`` with nodes on both sides: graphs as PyG
    tensors and each first node's partner (-1: none)."""
    out = []
    for inst in dataset.instances(split):
        if len(inst.first) == 0 or len(inst.second) == 0:
            continue
        graphs = [graph_of(side, scale, width)[1] for side in (inst.first, inst.second)]
        out.append((graphs[0], graphs[1], inst.y.copy()))
    return out


def collate(pairs):
    """DGMC's batched inputs and the padded sizes."""
    parts = []
    for side in (0, 1):
        xs, eis, eas, batch, offset = [], [], [], [], 0
        for k, p in enumerate(pairs):
            x, ei, ea = p[side]
            xs.append(x)
            eis.append(ei + offset)
            eas.append(ea)
            batch.append(torch.full((x.shape[0],), k, dtype=torch.long))
            offset += x.shape[0]
        parts.append((torch.cat(xs), torch.cat(eis, dim=1), torch.cat(eas), torch.cat(batch)))
    (xs, eis, eas, bs), (xt, eit, eat, bt) = parts
    return (xs, eis, eas, bs, xt, eit, eat, bt)


def label_weights(pairs, r, c, no_match):
    """coid's ``label_weights``: ``[B, r + 1, c + 1]``."""
    w = torch.zeros(len(pairs), r + 1, c + 1)
    for k, (g1, g2, y) in enumerate(pairs):
        n1, n2 = g1[0].shape[0], g2[0].shape[0]
        taken = np.zeros(n2, dtype=bool)
        for i, j in enumerate(y):
            if j >= 0:
                w[k, i, j] = 1.0
                taken[j] = True
            else:
                w[k, i, c] = 1.0
        for j in np.flatnonzero(~taken):
            w[k, r, j] = 1.0
        if no_match == "entries":
            w[k] /= max(float(w[k].sum()), 1.0)
        else:
            bins = torch.zeros(r + 1, c + 1, dtype=torch.bool)
            bins[r, :] = True
            bins[:, c] = True
            labelled = w[k] > 0
            n_bins = max(int((labelled & bins).sum()), 1)
            n_pairs = max(int((labelled & ~bins).sum()), 1)
            w[k] = torch.where(bins, w[k] * 0.5 / n_bins, w[k] * 0.5 / n_pairs)
    return w


def eq12_13(p, pairs, non_on, unc_on):
    """The paper's Eq. 12 and 13 per pair on the mean real block ``p``."""
    total = torch.zeros(())
    for k, (g1, g2, y) in enumerate(pairs):
        n1, n2 = g1[0].shape[0], g2[0].shape[0]
        q = p[k, :n1, :n2]
        col_has = np.zeros(n2, dtype=bool)
        col_has[y[y >= 0]] = True
        non = torch.from_numpy(((y < 0)[:, None] | ~col_has[None, :]).astype(np.float32))
        n_real = max(n1 * n2, 1)
        if non_on:
            total = total - torch.log(torch.exp(-(q * non)).sum() / n_real)
        if unc_on:
            qc = q.clamp(1e-6, 1 - 1e-6)
            h = -(qc * qc.log() + (1 - qc) * (1 - qc).log()) / math.log(2)
            total = total - torch.log(torch.exp(-h).sum() / n_real)
    return total / len(pairs)


def loss_of(net, pairs, samples, terms):
    """coid's published trainer's loss of a batch."""
    batch = collate(pairs)
    r = max(p[0][0].shape[0] for p in pairs)
    c = max(p[1][0].shape[0] for p in pairs)
    w = label_weights(pairs, r, c, terms["no_match"])
    loss = torch.zeros(())
    lasts = []
    for _ in range(samples):
        log0, log_l = net(batch)
        loss = loss - (log0 * w).sum() / (len(pairs) * samples)
        if net.cfg["consensus_steps"] > 0:
            loss = loss - (log_l * w).sum() / (len(pairs) * samples)
        lasts.append(log_l.exp())
    if terms["non"] or terms["unc"]:
        p = torch.stack(lasts).mean(0)[:, :-1, :-1]
        loss = loss + eq12_13(p, pairs, terms["non"], terms["unc"])
    return loss


def batches(sizes, batch_size, rng):
    """coid's ``batches``: shuffled, grouped by size in windows of 16
    batches, the batch order shuffled again."""
    order = list(range(len(sizes)))
    rng.shuffle(order)
    for w in range(0, len(order), batch_size * 16):
        order[w : w + batch_size * 16] = sorted(order[w : w + batch_size * 16], key=lambda k: sizes[k])
    out = [order[i : i + batch_size] for i in range(0, len(order), batch_size)]
    rng.shuffle(out)
    return out


def fnv64_hex(data: bytes) -> str:
    """coid's weights checksum (FNV-1a 64)."""
    h = 0xCBF29CE484222325
    for b in data:
        h = ((h ^ b) * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return f"{h:016x}"


def record_for(text: str, weights: bytes) -> str:
    """A coid record of the same recipe for these weights: its checksum
    theirs, its validated choices (the ``[validation]`` tables, which belong
    to other weights) left out."""
    out = []
    for line in text.splitlines():
        if line.startswith("[validation"):
            break
        if line.startswith("weights_fnv64 = "):
            line = f'weights_fnv64 = "{fnv64_hex(weights)}"'
        out.append(line)
    return "\n".join(out).rstrip() + "\n"


def shape_differences(record_text: str, cfg: dict) -> list:
    """The architecture keys of a coid record that differ from the network
    the reference trains (``cfg``: its published configuration): the
    reference convolves over the dataset's Delaunay edges, with the
    default edge scale and indicator width of ``--shape-of``."""
    arch = tomllib.loads(record_text).get("architecture", {})
    have = {"graph": arch.get("graph", "delaunay"), "edge_scale_m": arch.get("edge_scale_m"), "consensus_dim": arch.get("consensus_dim", arch.get("rnd_dim"))}
    wanted = {"graph": cfg.get("graph", "delaunay"), "edge_scale_m": cfg["edge_scale_m"], "consensus_dim": cfg["consensus_dim"]}
    return [f"{k} = {have[k]!r} (the reference: {v!r})" for k, v in wanted.items() if have[k] != v]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dgmc", type=Path, required=True)
    ap.add_argument("--dataset", type=Path, required=True)
    ap.add_argument("--method", default="coid", choices=["coid", "coid+non", "coid+unc", "dgmc", "gcn-gm"])
    ap.add_argument("--shape-of", type=Path, default=Path("models"), help="a models folder whose <method>.bpk gives the architecture")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--epochs", type=int, default=20)
    ap.add_argument("--learning-rate", type=float, default=2e-3)
    ap.add_argument("--batch-size", type=int, default=32)
    ap.add_argument("--patience", type=int, default=3)
    ap.add_argument("--samples", type=int, default=2)
    ap.add_argument("--no-match", choices=["entries", "halves"], default="halves")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--record", type=Path, help="coid's record (<method>.toml) of the same recipe, copied beside the weights with their checksum and without its validated choices, for `coid train --validate-only` and `coid eval`")
    args = ap.parse_args(argv)

    import coid_sim
    from coid_sim import _coid_sim

    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    rng = random.Random(args.seed)
    cfg = _coid_sim.PublishedNetwork(str(args.shape_of / f"{args.method}.bpk"), args.method).config()
    if args.record and (differ := shape_differences(args.record.read_text(), cfg)):
        print(f"train.py: {args.record} is another network than the reference trains: {'; '.join(differ)}", file=sys.stderr)
        return 2
    terms = {
        "no_match": args.no_match,
        "non": args.method in ("coid", "coid+non"),
        "unc": args.method in ("coid", "coid+unc"),
    }
    dataset = coid_sim.Dataset(args.dataset)
    train = pairs_of(dataset, "train", cfg["node_features"], cfg["edge_scale_m"])
    validation = pairs_of(dataset, "validation", cfg["node_features"], cfg["edge_scale_m"])
    net = Net(args.dgmc, cfg)
    optim = torch.optim.Adam(net.parameters(), lr=args.learning_rate, eps=1e-5)
    sizes = [max(p[0][0].shape[0], p[1][0].shape[0]) for p in train]
    per_epoch = math.ceil(len(train) / args.batch_size)
    total = args.epochs * per_epoch

    def validation_loss():
        state = torch.get_rng_state()
        torch.manual_seed(1_000_003)
        order = sorted(range(len(validation)), key=lambda k: max(validation[k][0][0].shape[0], validation[k][1][0].shape[0]))
        s = 0.0
        with torch.no_grad():
            for i in range(0, len(order), args.batch_size):
                chunk = [validation[k] for k in order[i : i + args.batch_size]]
                s += float(loss_of(net, chunk, args.samples, terms)) * len(chunk)
        torch.set_rng_state(state)
        return s / len(validation)

    net.train()
    best = (0, validation_loss(), net.parameters_by_name())
    print(f"{len(train)} training pairs, {len(validation)} validation pairs; epoch 0 validation loss {best[1]:.4f}", flush=True)
    step, rows = 0, [(0, None, best[1])]
    started = time.time()
    for epoch in range(1, args.epochs + 1):
        s = 0.0
        for chunk in batches(sizes, args.batch_size, rng):
            for g in optim.param_groups:
                g["lr"] = learning_rate(args.learning_rate, step, total)
            pairs = [train[k] for k in chunk]
            loss = loss_of(net, pairs, args.samples, terms)
            if not torch.isfinite(loss):
                print(f"training diverged (loss {float(loss)}) at step {step}", file=sys.stderr)
                return 1
            optim.zero_grad()
            loss.backward()
            optim.step()
            s += float(loss) * len(pairs)
            step += 1
            if step % 10 == 0:
                print(f"  step {step} of at most {total}: loss {float(loss):.4f} ({time.time() - started:.0f} s)", flush=True)
        v = validation_loss()
        rows.append((epoch, s / len(train), v))
        print(f"epoch {epoch}: train loss {s / len(train):.4f}, validation loss {v:.4f} ({time.time() - started:.0f} s)", flush=True)
        if v < best[1]:
            best = (epoch, v, net.parameters_by_name())
        elif epoch - best[0] >= args.patience:
            break
    args.out.mkdir(parents=True, exist_ok=True)
    bpk = _coid_sim.PublishedNetwork.weights_of(args.method, best[2])
    (args.out / f"{args.method}.bpk").write_bytes(bpk)
    if args.record:
        (args.out / f"{args.method}.toml").write_text(record_for(args.record.read_text(), bpk))
    with open(args.out / f"{args.method}_loss.csv", "w") as f:  # coid's loss curve's columns
        f.write(f"epoch,mean_loss,validation_loss\n0,,{rows[0][2]:.6f}\n")
        for e, t, v in rows[1:]:
            f.write(f"{e},{t:.6f},{v:.6f}\n")
    print(f"best epoch {best[0]} (validation loss {best[1]:.4f}); wrote {args.out / (args.method + '.bpk')} ({step} steps, {time.time() - started:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(one_line_errors(main))

"""Forward equivalence of coid's published networks with DGMC's reference
code (rusty1s/deep-graph-matching-consensus, PyTorch Geometric).

The same weights (coid's ``.bpk``, loaded by name into DGMC's modules), the
same pairs (a coid dataset's instances: coid's node attributes and Delaunay
graphs, each edge's length as its pseudo-coordinate over ``edge_scale_m``),
the same dropout masks and consensus indicators (drawn here and handed to
both) go through coid's plain inference (``coid_sim._coid_sim.
PublishedNetwork``) and through DGMC's ``DGMC.forward`` with PyG's
``SplineConv``. Where coid departs from DGMC on purpose, the departure is
put into DGMC's forward and named:

- psi_1 has the paper's sizes (a 256-channel then a 32-channel SplineConv,
  then DGMC's final linear layer) with dropout after the first ReLU; DGMC's
  ``SplineCNN`` has one width throughout and drops out before its final
  layer. Built here from PyG's ``SplineConv``.
- every normalisation is Sinkhorn with a dustbin row and column and one
  learned "no match" score (coid's, after SuperGlue), where DGMC uses a row
  softmax: ``dgmc.models.dgmc.masked_softmax`` is replaced.
- the random indicators are given (``torch.randn`` inside DGMC's forward
  returns them).

psi_2 is DGMC's ``SplineCNN(rnd_dim, rnd_dim, dim=1, num_layers=2,
cat=True)`` and the consensus MLP DGMC's own, unchanged. PyG's
``SplineConv`` needs pyg-lib for the degree-1 B-spline basis, which has no
wheel in the Python registry: ``spline_basis`` and ``spline_weighting``
below are those two functions in plain PyTorch (open splines, degree 1).

Prints the largest absolute difference of any assignment entry over all
pairs and samples, and exits 1 when it passes ``--tolerance``.
"""

from __future__ import annotations

import argparse
import math
import sys
import types
from pathlib import Path

import numpy as np
import torch


def spline_basis(pseudo, kernel_size, is_open_spline, degree):
    """PyG's open B-spline basis of degree 1 over ``pseudo`` in [0, 1]:
    ``[E, 2^dim]`` weights and kernel indices."""
    assert degree == 1 and bool(is_open_spline.all()), "open splines of degree 1 only"
    e, dim = pseudo.shape
    v = pseudo * (kernel_size.to(pseudo.dtype) - 1)
    low = v.floor()
    frac = v - low
    basis = torch.ones(e, 2**dim, dtype=pseudo.dtype)
    index = torch.zeros(e, 2**dim, dtype=torch.long)
    stride = 1
    for d in range(dim):
        bit = (torch.arange(2**dim) >> d) & 1  # which knot of dimension d
        basis = basis * torch.where(bit.bool(), frac[:, d : d + 1], 1 - frac[:, d : d + 1])
        k = (low[:, d : d + 1].long() + bit) % int(kernel_size[d])
        index = index + k * stride
        stride *= int(kernel_size[d])
    return basis, index


def spline_weighting(x_j, weight, basis, index):
    """Each message ``sum_s basis_s x_j W[index_s]``: ``x_j`` times every
    kernel matrix, then the two knots of each edge picked and weighed."""
    xw = torch.einsum("ei,kio->eko", x_j, weight)  # [E, K, out]
    picked = xw.gather(1, index.unsqueeze(-1).expand(-1, -1, xw.shape[2]))
    return (basis.unsqueeze(-1) * picked).sum(dim=1)


def load_dgmc(path: Path):
    """DGMC's package from a checkout at ``path``, with PyG's SplineConv given
    the basis above and ``torch_scatter`` (imported by DGMC, used only by its
    sparse variant) stood in for when it is not installed."""
    try:
        import torch_scatter  # noqa: F401
    except ImportError:
        shim = types.ModuleType("torch_scatter")

        def scatter_add(src, index, dim=-1, out=None, dim_size=None):
            raise NotImplementedError("DGMC's sparse variant is not used here")

        shim.scatter_add = scatter_add
        sys.modules["torch_scatter"] = shim
    import torch_geometric.nn.conv.spline_conv as pyg_spline

    if pyg_spline.spline_basis is None:
        pyg_spline.spline_basis = spline_basis
        pyg_spline.spline_weighting = spline_weighting
    sys.path.insert(0, str(path))
    import dgmc.models.dgmc as dgmc_module
    from dgmc.models import DGMC, SplineCNN

    return dgmc_module, DGMC, SplineCNN


class Psi1(torch.nn.Module):
    """The paper's psi_1 as coid runs it: SplineConv F -> hidden, ReLU, the
    given dropout mask, SplineConv hidden -> out, ReLU, DGMC's final linear
    layer. ``masks`` is consumed in call order (DGMC embeds the source graph,
    then the target)."""

    def __init__(self, f: int, hidden: int, out: int):
        super().__init__()
        from torch_geometric.nn import SplineConv

        self.conv1 = SplineConv(f, hidden, dim=1, kernel_size=5)
        self.conv2 = SplineConv(hidden, out, dim=1, kernel_size=5)
        self.final = torch.nn.Linear(out, out)
        self.masks: list = []

    def forward(self, x, edge_index, edge_attr, *args):
        h = torch.relu(self.conv1(x, edge_index, edge_attr))
        h = h * self.masks.pop(0)
        h = torch.relu(self.conv2(h, edge_index, edge_attr))
        return self.final(h)


def dustbin_sinkhorn(scores, bin_score: float, iters: int):
    """coid's normalisation: log-domain Sinkhorn over the scores with a
    dustbin row and column of score ``bin_score``, marginals 1 per node and
    ``n2`` (``n1``) for the dustbins over ``n1 + n2``, scaled back by ``n1 +
    n2``: ``(n1 + 1) x (n2 + 1)``."""
    n1, n2 = scores.shape
    z = torch.full((n1 + 1, n2 + 1), float(bin_score), dtype=torch.float64)
    z[:n1, :n2] = scores.double()
    norm = -math.log(n1 + n2)
    log_mu = torch.cat([torch.full((n1,), norm, dtype=torch.float64), torch.tensor([math.log(n2) + norm], dtype=torch.float64)])
    log_nu = torch.cat([torch.full((n2,), norm, dtype=torch.float64), torch.tensor([math.log(n1) + norm], dtype=torch.float64)])
    u = torch.zeros(n1 + 1, dtype=torch.float64)
    v = torch.zeros(n2 + 1, dtype=torch.float64)
    for _ in range(iters):
        u = log_mu - torch.logsumexp(z + v[None, :], dim=1)
        v = log_nu - torch.logsumexp(z + u[:, None], dim=0)
    return torch.exp(z + u[:, None] + v[None, :] - norm)


class Reference:
    """DGMC's forward with coid's three departures put in (module doc)."""

    def __init__(self, dgmc_path: Path, config: dict, params: dict):
        self.module, DGMC, SplineCNN = load_dgmc(dgmc_path)
        c = config
        self.config = c
        r = c["consensus_dim"]
        self.psi1 = Psi1(c["node_features"], c["hidden"], c["out"])
        psi2 = SplineCNN(r, r, 1, 2, cat=True, lin=True, dropout=0.0)
        self.model = DGMC(self.psi1, psi2, num_steps=c["consensus_steps"])
        self.model.eval()
        self.dustbin = params["dustbin"][1][0]
        self._load(params, c["consensus_steps"] > 0)
        self.last = None
        self.indicators: list = []
        module = self.module

        def masked_softmax(src, mask, dim=-1):
            assert src.shape[0] == 1, "one pair at a time"
            n1, n2 = int(mask[0].any(1).sum()), int(mask[0].any(0).sum())
            full = dustbin_sinkhorn(src[0, :n1, :n2], self.dustbin, c["sinkhorn_iters"])
            self.last = full
            out = torch.zeros_like(src)
            out[0, :n1, :n2] = full[:n1, :n2].to(src.dtype)
            return out

        real_torch = torch

        class TorchGiven(types.ModuleType):
            def __getattr__(self, name):
                return getattr(real_torch, name)

        given = TorchGiven("torch")
        given.randn = lambda size, dtype=None, device=None: self.indicators.pop(0).reshape(size).to(dtype)
        module.masked_softmax = masked_softmax
        module.torch = given

    def _load(self, params: dict, consensus: bool):
        def t(name):
            shape, values = params[name]
            return torch.tensor(values, dtype=torch.float32).reshape(shape)

        def conv(layer, name):
            w = t(f"{name}.weight")  # [in, knots * out]
            d_in, d_out = w.shape[0], layer.out_channels
            layer.weight.data = w.reshape(d_in, 5, d_out).permute(1, 0, 2).contiguous()
            layer.lin.weight.data = t(f"{name}.root").T.contiguous()
            layer.bias.data = t(f"{name}.bias")

        def linear(layer, name):
            layer.weight.data = t(f"{name}.weight").T.contiguous()
            layer.bias.data = t(f"{name}.bias")

        conv(self.psi1.conv1, "psi1.conv1")
        conv(self.psi1.conv2, "psi1.conv2")
        linear(self.psi1.final, "psi1.last")
        if consensus:
            psi2 = self.model.psi_2
            conv(psi2.convs[0], "psi2.conv1")
            conv(psi2.convs[1], "psi2.conv2")
            linear(psi2.final, "psi2.last")
            linear(self.model.mlp[0], "mlp_in")
            linear(self.model.mlp[2], "mlp_out")

    @torch.no_grad()
    def forward(self, graphs, masks, indicators):
        """One sample: ``graphs`` two ``(x [n, F], edge_index [2, 2e],
        pseudo [2e, 1])``, ``masks`` psi_1's two ``[n, hidden]``,
        ``indicators`` one ``[n1, rnd]`` per step ->
        ``(n1 + 1) x (n2 + 1)``."""
        (x_s, ei_s, ea_s), (x_t, ei_t, ea_t) = graphs
        self.psi1.masks = list(masks)
        self.indicators = list(indicators)
        self.model(x_s, ei_s, ea_s, None, x_t, ei_t, ea_t, None)
        assert not self.indicators and not self.psi1.masks
        return self.last


def graph_of(side, scale_m: float, width: int):
    """coid's input of one vehicle: its node attributes (the first ``width``
    of them: class, colour, size and as much of the appearance vector as the
    network reads), its Delaunay edges and their lengths (coid's), and PyG's
    form of the same."""
    x = np.ascontiguousarray(side.network_features()[:, :width].astype(np.float32))
    edges = side.edges()
    lengths = np.linalg.norm(side.xy_m[edges[:, 0]] - side.xy_m[edges[:, 1]], axis=1) if len(edges) else np.zeros(0)
    both = np.concatenate([edges, edges[:, ::-1]], axis=0).T.copy() if len(edges) else np.zeros((2, 0), dtype=np.int64)
    pseudo = np.clip(np.concatenate([lengths, lengths]).astype(np.float32) / np.float32(scale_m), 0.0, 1.0)
    coid = (x.reshape(-1).tolist(), [tuple(map(int, e)) for e in edges], lengths.tolist())
    pyg = (torch.from_numpy(x), torch.from_numpy(both).long(), torch.from_numpy(pseudo).reshape(-1, 1))
    return coid, pyg


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dgmc", type=Path, required=True, help="a checkout of rusty1s/deep-graph-matching-consensus")
    ap.add_argument("--dataset", type=Path, required=True, help="a coid dataset folder (coid export, coid convert pyg)")
    ap.add_argument("--weights", type=Path, default=Path("models/coid.bpk"))
    ap.add_argument("--method", default="coid", help="the network the weights are of (coid, dgmc, gcn-gm, ...)")
    ap.add_argument("--split", default="validation")
    ap.add_argument("--pairs", type=int, default=300, help="pairs checked (the first of the split)")
    ap.add_argument("--samples", type=int, default=2, help="MC samples per pair, each with its own draws")
    ap.add_argument("--seed", type=int, default=0, help="seed of the masks and indicators drawn here")
    ap.add_argument("--appearance-width", type=int, default=0, help="the width of the appearance vectors the weights read (0: none; the dataset's are cut to it)")
    ap.add_argument("--tolerance", type=float, default=1e-4)
    args = ap.parse_args(argv)

    import coid_sim
    from coid_sim import _coid_sim

    dataset = coid_sim.Dataset(args.dataset)
    net = _coid_sim.PublishedNetwork(str(args.weights), args.method, appearance_width=args.appearance_width, samples=args.samples)
    config = net.config()
    ref = Reference(args.dgmc, config, net.parameters())
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    p = config["dropout_conv"]
    t, hidden, r, steps = args.samples, config["hidden"], config["consensus_dim"], config["consensus_steps"]
    worst, checked, entries, diffs = 0.0, 0, 0, []
    for inst in dataset.instances(args.split):
        n1, n2 = len(inst.first), len(inst.second)
        if n1 == 0 or n2 == 0:
            continue
        scale, width = config["edge_scale_m"], config["node_features"]
        (c1, g1), (c2, g2) = graph_of(inst.first, scale, width), graph_of(inst.second, scale, width)
        masks = [((rng.random((t, n, hidden)) >= p) / (1 - p)).astype(np.float32) for n in (n1, n2)]
        indicators = [rng.standard_normal((t, n1, r)).astype(np.float32) for _ in range(steps)]
        ours = net.forward(c1, c2, (masks[0].reshape(-1).tolist(), masks[1].reshape(-1).tolist()), [i.reshape(-1).tolist() for i in indicators])
        for s in range(t):
            theirs = ref.forward((g1, g2), [torch.from_numpy(m[s]) for m in masks], [torch.from_numpy(i[s]) for i in indicators]).numpy()
            d = np.abs(np.asarray(ours[s], dtype=np.float64).reshape(n1 + 1, n2 + 1) - theirs)
            worst = max(worst, float(d.max()))
            diffs.append(d.reshape(-1))
            entries += d.size
        checked += 1
        if checked == args.pairs:
            break
    if checked == 0:
        print(f"no pair with nodes on both sides in {args.dataset}'s {args.split} split", file=sys.stderr)
        return 1
    all_d = np.concatenate(diffs)
    print(
        f"{args.method} ({args.weights}): {checked} pairs of {args.dataset} ({args.split}), {t} samples each, "
        f"{entries} assignment entries: largest difference {worst:.2e}, 99th percentile {np.quantile(all_d, 0.99):.2e} "
        f"(tolerance {args.tolerance:g})"
    )
    return 0 if worst <= args.tolerance else 1


def one_line_errors(run) -> int:
    """``run()``'s exit code; coid's refusals and missing files as one
    line and exit 1, not a traceback."""
    from coid_sim import CoidError

    try:
        return run()
    except (CoidError, OSError) as e:
        print(f"{Path(sys.argv[0]).name}: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(one_line_errors(main))

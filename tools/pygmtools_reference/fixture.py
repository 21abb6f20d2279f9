"""Writes the pygmtools reference that coid's spectral and RRWM solvers are
checked against (`src/matching/spectral_reference.json`, read by the unit
test `rrwm_and_spectral_agree_with_pygmtools`).

    python -m venv /tmp/pgm && /tmp/pgm/bin/pip install -r tools/pygmtools_reference/requirements.txt
    /tmp/pgm/bin/python tools/pygmtools_reference/fixture.py > src/matching/spectral_reference.json

Instances: seeded random symmetric non-negative affinities over every
(i, a) of an n1 x n2 assignment (square, wide and tall), and ones where only
some (i, a) are candidates (the other rows and columns of K are zero), as
coid's plain affinity builds them. K is indexed as pygmtools indexes it: the
column-major vectorisation of the n1 x n2 assignment (a * n1 + i).
"""
import json
import sys

import numpy as np
import pygmtools as pygm

pygm.set_backend("numpy")


def instance(rng, n1, n2, keep):
    cells = n1 * n2
    m = rng.random((cells, cells))
    k = (m + m.T) / 2
    k[k < 0.4] = 0.0
    candidates = [c for c in range(cells) if rng.random() < keep]
    mask = np.zeros(cells, dtype=bool)
    mask[candidates] = True
    k[~mask, :] = 0.0
    k[:, ~mask] = 0.0
    np.fill_diagonal(k, 0.0)
    x_rrwm = pygm.rrwm(k[None], np.array([n1]), np.array([n2]))[0]
    x_sm = pygm.sm(k[None], np.array([n1]), np.array([n2]), max_iter=1000)[0]
    return {
        "n1": n1,
        "n2": n2,
        # (i, a) of each candidate, in column-major order
        "candidates": [[c % n1, c // n1] for c in candidates],
        "k_column_major": k.reshape(-1).tolist(),
        "rrwm_row_major": x_rrwm.reshape(-1).tolist(),
        "sm_row_major": x_sm.reshape(-1).tolist(),
    }


def main():
    rng = np.random.default_rng(65)
    shapes = [(3, 3, 1.0), (3, 5, 1.0), (6, 4, 1.0), (5, 5, 0.6), (4, 7, 0.5), (8, 6, 0.4)]
    json.dump(
        {
            "pygmtools": pygm.__version__,
            "instances": [instance(rng, n1, n2, keep) for n1, n2, keep in shapes],
        },
        sys.stdout,
        indent=None,
    )
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()

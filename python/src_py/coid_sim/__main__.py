"""``python -m coid_sim`` (and the ``coid`` script): the ``coid`` program,
run by this interpreter. A batch's workers and training's children are
started this way inside the package."""

import sys

from . import _coid_sim


def main() -> None:
    sys.exit(_coid_sim.main(["coid", *sys.argv[1:]]))


if __name__ == "__main__":
    main()

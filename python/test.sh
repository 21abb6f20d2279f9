#!/usr/bin/env bash
# Builds the wheel (maturin, from python/) and tests it as a user gets it:
# installed with pip into a fresh virtual environment (SUMO's wheels come
# with it), pytest run there from outside the source tree. The `coid`
# binary the tests compare with is $COID_BIN [default: the release build
# in $CARGO_TARGET_DIR or target/]. Extra arguments go to pytest.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
target="${CARGO_TARGET_DIR:-$root/target}"
python="${COID_PYTHON:-python3}"
# maturin in its own environment, kept beside the build.
tools="$target/python-tools"
if ! [ -x "$tools/bin/maturin" ]; then
    "$python" -m venv "$tools"
    "$tools/bin/python" -m pip install --disable-pip-version-check --quiet "maturin==1.16.0"
fi
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
started=$SECONDS
(cd "$root" && "$tools/bin/maturin" build --release --quiet -m python/Cargo.toml -o "$work/dist" -i "$python")
wheel="$(ls "$work"/dist/coid_sim-*.whl)"
echo "python/test.sh: built $(basename "$wheel") ($(du -h "$wheel" | cut -f1)) in $((SECONDS - started)) s" >&2
"$python" -m venv "$work/venv"
"$work/venv/bin/python" -m pip install --disable-pip-version-check --quiet "$wheel[pandas]" pytest
cd "$work"
COID_BIN="${COID_BIN:-$target/release/coid}" COID_VENV="${COID_VENV:-$root/.venv}" \
    "$work/venv/bin/python" -m pytest -q -p no:cacheprovider "$root/python/tests" "$@"

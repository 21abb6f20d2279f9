#!/usr/bin/env bash
# Usage: tools/dgmc_reference/run.sh check|train DGMC_CHECKOUT [options]
# Makes the reference's environment beside the build (torch, PyTorch
# Geometric and coid's wheel, built from python/), then runs check.py or
# train.py in it from the repository's root.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
target="${CARGO_TARGET_DIR:-$root/target}"
env="$target/dgmc-reference-venv"
usage="usage: tools/dgmc_reference/run.sh check|train DGMC_CHECKOUT [options]"
script="${1:?$usage}"
dgmc="${2:?$usage}"
shift 2
case "$script" in
    check | train) ;;
    *) echo "$usage" >&2; exit 2 ;;
esac
if ! [ -x "$env/bin/python" ]; then
    python3 -m venv "$env"
    "$env/bin/python" -m pip install --disable-pip-version-check --quiet -r "$root/tools/dgmc_reference/requirements.txt" maturin==1.16.0
fi
"$env/bin/maturin" build --release --quiet -m "$root/python/Cargo.toml" -o "$env/dist" -i "$env/bin/python"
"$env/bin/python" -m pip install --disable-pip-version-check --quiet --force-reinstall --no-deps "$env"/dist/coid_sim-*.whl
"$env/bin/python" -m pip install --disable-pip-version-check --quiet "polars>=1"
cd "$root"
exec "$env/bin/python" -W ignore "tools/dgmc_reference/$script.py" --dgmc "$dgmc" "$@"

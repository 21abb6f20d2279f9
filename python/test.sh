#!/usr/bin/env bash
# Builds the package as it is distributed and tests it as a user gets it:
# 1. the wheel, manylinux2014 (maturin with zig as the linker: glibc 2.17,
#    so any Linux of the last decade installs it; maturin refuses the tag
#    if a symbol is newer);
# 2. the sdist, and a wheel built from nothing but its unpacked files
#    (so that it holds everything the build reads);
# 3. the manylinux2014 wheel installed with pip into a fresh virtual
#    environment (SUMO's wheels come with it), pytest run there from
#    outside the source tree.
# The `coid` binary the tests compare with is $COID_BIN [default: the
# release build in $CARGO_TARGET_DIR or target/]. Extra arguments go to
# pytest. The wheel and sdist are left in $COID_DIST when it is set.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
target="${CARGO_TARGET_DIR:-$root/target}"
python="${COID_PYTHON:-python3}"
# maturin and zig in their own environment, kept beside the build, made
# again when python/build-requirements.txt changes.
tools="$target/python-tools"
requirements="$root/python/build-requirements.txt"
if ! cmp -s "$requirements" "$tools/requirements.txt"; then
    rm -rf "$tools"
    "$python" -m venv "$tools"
    "$tools/bin/python" -m pip install --disable-pip-version-check --quiet -r "$requirements"
    cp "$requirements" "$tools/requirements.txt"
fi
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
dist="$work/dist"
started=$SECONDS
# maturin finds zig on PATH (the ziglang package's `python -m ziglang`).
(cd "$root" && PATH="$tools/bin:$PATH" "$tools/bin/maturin" build --release --quiet --zig \
    --compatibility manylinux2014 -m python/Cargo.toml -o "$dist" -i "$python")
wheel="$(ls "$dist"/coid_sim-*.whl)"
case "$(basename "$wheel")" in
    *manylinux2014_x86_64*) ;;
    *) echo "python/test.sh: $(basename "$wheel") is not a manylinux2014 wheel" >&2; exit 1 ;;
esac
echo "python/test.sh: built $(basename "$wheel") ($(du -h "$wheel" | cut -f1)) in $((SECONDS - started)) s" >&2
started=$SECONDS
(cd "$root" && "$tools/bin/maturin" sdist -m python/Cargo.toml -o "$dist" > /dev/null)
sdist="$(ls "$dist"/coid_sim-*.tar.gz)"
mkdir "$work/sdist"
tar xzf "$sdist" -C "$work/sdist"
(cd "$work/sdist"/coid_sim-* && CARGO_TARGET_DIR="$target" "$tools/bin/maturin" build --release --quiet \
    -m python/Cargo.toml -o "$work/from-sdist" -i "$python")
echo "python/test.sh: built $(basename "$sdist") ($(du -h "$sdist" | cut -f1)) and a wheel from it alone in $((SECONDS - started)) s" >&2
if [ -n "${COID_DIST:-}" ]; then
    mkdir -p "$COID_DIST"
    cp "$wheel" "$sdist" "$COID_DIST"/
fi
"$python" -m venv "$work/venv"
"$work/venv/bin/python" -m pip install --disable-pip-version-check --quiet "$wheel[pandas]" pytest
cd "$work"
COID_BIN="${COID_BIN:-$target/release/coid}" COID_VENV="${COID_VENV:-$root/.venv}" \
    "$work/venv/bin/python" -m pytest -q -p no:cacheprovider "$root/python/tests" "$@"

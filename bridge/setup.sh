#!/usr/bin/env bash
# Creates the project-local Python environment (.venv) with the pinned SUMO
# packages from PyPI. Idempotent: does nothing
# when the environment is already complete. Needs only python3 (3.11) with pip and venv.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
venv="$root/.venv"
req="$root/bridge/requirements.txt"
stamp="$venv/.coid-requirements"
python="${COID_PYTHON:-python3}"
if ! { [ -x "$venv/bin/python" ] && [ -f "$stamp" ] && cmp -s "$req" "$stamp"; }; then
    echo "coid: setting up the Python environment in $venv (libsumo, eclipse-sumo; ~250 MB, once)" >&2
    "$python" -m venv "$venv"
    "$venv/bin/python" -m pip install --disable-pip-version-check --quiet -r "$req"
    "$venv/bin/python" -c "import libsumo, sumo; print('coid: libsumo', libsumo.__file__.rsplit('/', 2)[0], 'SUMO_HOME', sumo.SUMO_HOME)" >&2
    cp "$req" "$stamp"
fi

#!/usr/bin/env bash
# Rebuilds intersection.net.xml from the plain-XML sources with netconvert from
# the project-local SUMO (run bridge/setup.sh once first). The demand
# (intersection.rou.xml) and the buildings (buildings.poly.xml) are hand-kept
# sources and are not generated.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
netconvert="$here/../../.venv/bin/netconvert"
"$netconvert" \
    --node-files "$here/intersection.nod.xml" \
    --edge-files "$here/intersection.edg.xml" \
    --crossings.guess true \
    --walkingareas true \
    --tls.default-type static \
    --junctions.corner-detail 5 \
    --no-turnarounds true \
    --offset.disable-normalization true \
    --output-file "$here/intersection.net.xml"

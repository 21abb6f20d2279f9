#!/usr/bin/env bash
# Builds two networks this project did not hand-write, to check that any
# SUMO scenario runs by configuration alone (docs/networks.md):
#
#   <out>/grid/  netgenerate's 5 x 5 signalised grid (2 lanes, sidewalks,
#                crossings), no buildings; junction C2 in the middle.
#   <out>/town/  an OSM-like town (irregular blocks, a 2-lane avenue, two
#                nodes 6 m apart that netconvert joins into a cluster,
#                buildings tagged building=yes/residential/...) imported
#                with netconvert and polyconvert and SUMO's OSM typemaps, so
#                buildings have polygon types building.*; the junction is
#                named by one of the joined node ids.
#   <out>/densetown/  the same town with three times the traffic, departing
#                until 900 s: the city-scale benchmark's network
#                (benches/scale.sh).
#
# Demand for both: randomTrips (seeded) with the shipped intersection's
# vehicle classes and colours (vtypes.add.xml) and pedestrians. Each folder
# gets a .sumocfg and a coid config (coid.toml: [scenario] and [connected]
# only, penetration 0.3). Needs the project's .venv (bridge/setup.sh).
#
#   sumo_nets/checks/make_foreign.sh /tmp/foreign
#   ./coid eval --config /tmp/foreign/town/coid.toml
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="${1:?usage: make_foreign.sh OUT_DIR}"
py="$here/../../.venv/bin/python"
bin="$here/../../.venv/bin"
sumo_home="$("$py" -c 'import sumo; print(sumo.SUMO_HOME)')"
export SUMO_HOME="$sumo_home"
export PROJ_DATA="$sumo_home/data/proj" PROJ_LIB="$sumo_home/data/proj"
mkdir -p "$out/grid" "$out/town"
out="$(cd "$out" && pwd)"

demand() { # net, prefix, period, seed, [end of departures, s]
    local net="$1" end="${5:-400}" dir; dir="$(dirname "$net")"
    "$py" "$sumo_home/tools/randomTrips.py" -n "$net" -o "$dir/trips.xml" -r "$dir/routes.rou.xml" \
        --additional-file "$here/../vtypes.add.xml" --trip-attributes 'type="mix" departLane="best"' \
        --period "$3" --seed "$4" --fringe-factor 5 --end "$end" --validate --prefix "$2" >/dev/null
    # -r: with --pedestrians, randomTrips also routes the walks, by default
    # into routes.rou.xml of the working directory; SUMO routes them itself.
    "$py" "$sumo_home/tools/randomTrips.py" -n "$net" -o "$dir/walks.rou.xml" -r "$dir/walks.routed.xml" \
        --pedestrians --period 4 --seed "$4" --end "$end" --prefix "${2}p" >/dev/null
    rm -f "$dir/walks.routed.xml"
}

sumocfg() { # dir, net, additional files (the routes carry the vehicle types)
    local extra=""
    if [ -n "${3:-}" ]; then extra="<additional-files value=\"$3\"/>"; fi
    cat > "$1/scenario.sumocfg" <<EOF
<configuration>
    <input>
        <net-file value="$2"/>
        <route-files value="routes.rou.xml,walks.rou.xml"/>
        $extra
    </input>
    <time><begin value="0"/><step-length value="0.5"/></time>
    <processing><pedestrian.model value="striping"/></processing>
</configuration>
EOF
}

# --- grid ------------------------------------------------------------------
"$bin/netgenerate" --grid --grid.number 5 --grid.length 110 --default.lanenumber 2 \
    --sidewalks.guess --crossings.guess --tls.guess --no-turnarounds \
    --output-file "$out/grid/grid.net.xml" >/dev/null
demand "$out/grid/grid.net.xml" g 1.2 11
sumocfg "$out/grid" grid.net.xml
cat > "$out/grid/coid.toml" <<EOF
[scenario]
sumocfg = "scenario.sumocfg"
junction = "C2"
end_s = 300
[connected]
penetration = 0.3
EOF

# --- town (OSM-like) ----------------------------------------------------------
"$py" - "$out/town/town.osm" <<'PY'
import math, random, sys
random.seed(7)
lat0, lon0 = 52.5200, 13.4000
m_lat = 1 / 111_320.0
m_lon = 1 / (111_320.0 * math.cos(math.radians(lat0)))
xs = [0, 105, 230, 330, 460]          # irregular block widths (m)
ys = [0, 95, 215, 320]
nodes, ways, nid = [], [], 1000
grid = {}
for j, y in enumerate(ys):
    for i, x in enumerate(xs):
        jx, jy = random.uniform(-8, 8), random.uniform(-8, 8)
        grid[i, j] = nid
        nodes.append((nid, x + jx, y + jy)); nid += 1
# A dog-leg: the middle crossing is two nodes 6 m apart (joined by netconvert).
mid = grid[2, 1]
_, mx, my = next(n for n in nodes if n[0] == mid)
twin = nid; nodes.append((twin, mx + 6.0, my + 1.0)); nid += 1
wid = 1
def way(refs, tags):
    global wid
    ways.append((wid, refs, tags)); wid += 1
for j in range(len(ys)):
    row = [grid[i, j] for i in range(len(xs))]
    if j == 1:
        row = row[:3] + [twin] + row[3:]
    kind = "primary" if j == 1 else "residential"
    lanes = "2" if j == 1 else "1"
    way(row, {"highway": kind, "lanes": lanes, "name": f"Street {j}"})
for i in range(len(xs)):
    col = [grid[i, j] for j in range(len(ys))]
    if i == 2:
        # The avenue's south part meets the street at the twin node.
        way(col[:2], {"highway": "residential", "name": f"Avenue {i} north"})
        way([twin] + col[2:], {"highway": "residential", "name": f"Avenue {i} south"})
        continue
    way(col, {"highway": "residential", "name": f"Avenue {i}"})
# Buildings: rectangles inside blocks, set back 6-12 m, some blocks empty.
kinds = ["yes", "residential", "apartments", "commercial", "retail"]
for j in range(len(ys) - 1):
    for i in range(len(xs) - 1):
        if random.random() < 0.2:
            continue
        x0, x1, y0, y1 = xs[i], xs[i + 1], ys[j], ys[j + 1]
        for (u0, u1) in [(0.0, 0.45), (0.55, 1.0)]:
            back = random.uniform(6, 12)
            bx0, bx1 = x0 + back + u0 * (x1 - x0 - 2 * back), x0 + back + u1 * (x1 - x0 - 2 * back)
            by0, by1 = y0 + back, y0 + back + random.uniform(12, 30)
            ref = []
            for (px, py) in [(bx0, by0), (bx1, by0), (bx1, by1), (bx0, by1)]:
                nodes.append((nid, px, py)); ref.append(nid); nid += 1
            way(ref + [ref[0]], {"building": random.choice(kinds)})
with open(sys.argv[1], "w") as f:
    f.write('<?xml version="1.0" encoding="UTF-8"?>\n<osm version="0.6" generator="coid-sim make_foreign.sh">\n')
    for n, x, y in nodes:
        f.write(f'  <node id="{n}" lat="{lat0 + y * m_lat:.7f}" lon="{lon0 + x * m_lon:.7f}" version="1"/>\n')
    for w, refs, tags in ways:
        f.write(f'  <way id="{w}" version="1">\n')
        for r in refs:
            f.write(f'    <nd ref="{r}"/>\n')
        for k, v in tags.items():
            f.write(f'    <tag k="{k}" v="{v}"/>\n')
        f.write('  </way>\n')
    f.write('</osm>\n')
print(mid)
PY
"$bin/netconvert" --osm-files "$out/town/town.osm" \
    --type-files "$sumo_home/data/typemap/osmNetconvert.typ.xml" \
    --junctions.join --tls.guess-signals --sidewalks.guess --crossings.guess \
    --geometry.remove --no-turnarounds --output-file "$out/town/town.net.xml" >/dev/null 2>&1
"$bin/polyconvert" --osm-files "$out/town/town.osm" --net-file "$out/town/town.net.xml" \
    --type-file "$sumo_home/data/typemap/osmPolyconvert.typ.xml" --osm.keep-full-type \
    --output-file "$out/town/town.poly.xml" >/dev/null 2>&1
demand "$out/town/town.net.xml" t 1.0 12
sumocfg "$out/town" town.net.xml town.poly.xml
# The dog-leg crossing's first node (node 1007), which netconvert joined
# into a cluster with its twin.
cat > "$out/town/coid.toml" <<EOF
[scenario]
sumocfg = "scenario.sumocfg"
junction = "1007"
end_s = 300
[connected]
penetration = 0.3
EOF
# --- densetown: the town with three times the traffic --------------------------
mkdir -p "$out/densetown"
cp "$out/town/town.net.xml" "$out/town/town.poly.xml" "$out/densetown/"
demand "$out/densetown/town.net.xml" d 0.33 13 900
sumocfg "$out/densetown" town.net.xml town.poly.xml
cp "$out/town/coid.toml" "$out/densetown/coid.toml"
echo "made $out/grid, $out/town and $out/densetown"

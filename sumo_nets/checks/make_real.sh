#!/usr/bin/env bash
# Builds coid scenarios on real networks that ship inside the eclipse-sumo
# wheel (so nothing is downloaded), configured as a new user would: the
# network as it comes, seeded random demand (randomTrips), the junction
# picked by one stated rule (the signalised junction with the most incoming
# lanes; ties by id), and a coid.toml with [scenario] and [connected] only
# (penetration 0.3, 300 s). Nobody trains on these; their roles are fixed
# here, before any result is seen:
#
#   validation (may inform design choices, like the generated validation family):
#     drt         an OSM city extract (SUMO's DRT game), a 10-leg joined cluster
#     rilsa3      RiLSA example 3: a signalised 4-leg crossing from the German guideline
#   test (reported only; never used to choose anything):
#     ingolstadt  Ingolstadt (fkk_in game): a 5-leg arterial crossing, 19 incoming lanes
#     fokr_bs     Braunschweig's research crossing (fokr_bs game): 4 legs, 30 incoming lanes
#     bs          Braunschweig (bs3d game): 4-leg joined cluster, 8 incoming lanes
#     a10kw       an OSM extract around a motorway junction (A10KW game), with buildings
#
# Demand departs until 400 s (coid.toml runs 300 s); a second argument
# sets another end, for longer runs (the city-scale benchmark runs 800 s).
# A third, "plain", gives the vehicles SUMO's default type instead of the
# shipped classes and colours (one car of one colour, as randomTrips
# makes it without a type file): networks where appearance says almost
# nothing.
#
#   sumo_nets/checks/make_real.sh /tmp/real [DEMAND_END_S] [mix|plain]
#   ./coid eval --config /tmp/real/ingolstadt/coid.toml
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="${1:?usage: make_real.sh OUT_DIR [DEMAND_END_S] [mix|plain]}"
demand_end="${2:-400}"
demand="${3:-mix}"
case "$demand" in
    mix) types=(--additional-file "$here/../vtypes.add.xml" --trip-attributes 'type="mix" departLane="best"') ;;
    plain) types=(--trip-attributes 'departLane="best"') ;;
    *) echo "make_real.sh: demand must be mix or plain, not $demand" >&2; exit 2 ;;
esac
py="$here/../../.venv/bin/python"
sumo_home="$("$py" -c 'import sumo; print(sumo.SUMO_HOME)')"
export SUMO_HOME="$sumo_home" PYTHONPATH="$sumo_home/tools"
game="$sumo_home/tools/game"
mkdir -p "$out"
out="$(cd "$out" && pwd)"

# name, net, period of vehicle departures (s), seed, [buildings]
make() {
    local name="$1" net="$2" period="$3" seed="$4" poly="${5:-}" dir="$out/$1"
    mkdir -p "$dir"
    case "$net" in
        *.gz) gzip -dc "$net" > "$dir/net.net.xml" ;;
        *) cp "$net" "$dir/net.net.xml" ;;
    esac
    local extra=""
    if [ -n "$poly" ]; then
        cp "$poly" "$dir/buildings.poly.xml"
        extra='<additional-files value="buildings.poly.xml"/>'
    fi
    "$py" "$sumo_home/tools/randomTrips.py" -n "$dir/net.net.xml" -o "$dir/trips.xml" \
        -r "$dir/routes.rou.xml" "${types[@]}" --period "$period" --seed "$seed" \
        --fringe-factor 5 --end "$demand_end" --validate --prefix v >/dev/null 2>&1
    # -r: with --pedestrians, randomTrips also routes the walks, by default
    # into routes.rou.xml of the working directory; SUMO routes them itself.
    "$py" "$sumo_home/tools/randomTrips.py" -n "$dir/net.net.xml" -o "$dir/walks.rou.xml" \
        -r "$dir/walks.routed.xml" --pedestrians --period 2 --seed "$seed" --end "$demand_end" --prefix p \
        >/dev/null 2>&1
    rm -f "$dir/walks.routed.xml"
    cat > "$dir/scenario.sumocfg" <<EOF
<configuration>
    <input>
        <net-file value="net.net.xml"/>
        <route-files value="routes.rou.xml,walks.rou.xml"/>
        $extra
    </input>
    <time><begin value="0"/><step-length value="0.5"/></time>
    <processing><pedestrian.model value="striping"/><ignore-route-errors value="true"/></processing>
    <report><no-warnings value="true"/></report>
</configuration>
EOF
    local junction
    junction="$("$py" - "$dir/net.net.xml" <<'PY'
import sys, sumolib
net = sumolib.net.readNet(sys.argv[1])
tls = [n for n in net.getNodes() if n.getType() == "traffic_light"]
lanes = lambda n: sum(e.getLaneNumber() for e in n.getIncoming())
print(sorted(tls, key=lambda n: (-lanes(n), n.getID()))[0].getID())
PY
)"
    cat > "$dir/coid.toml" <<EOF
# $name: a real network shipped with SUMO; junction: the signalised one with
# the most incoming lanes; $demand demand. Made by sumo_nets/checks/make_real.sh.
[scenario]
sumocfg = "scenario.sumocfg"
junction = "$junction"
end_s = 300
[connected]
penetration = 0.3
EOF
}

make drt "$game/DRT/osm.net.xml" 0.25 21
make rilsa3 "$sumo_home/tools/sumolib/scenario/scenarios/RealWorld/RiLSA_example3/net.net.xml" 0.8 22
make ingolstadt "$game/fkk_in/ingolstadt.net.xml.gz" 0.8 23
make fokr_bs "$game/fokr_bs_demo/fokr_bs.net.xml.gz" 0.6 24
make bs "$game/bs3d/bs.net.xml" 0.5 25
make a10kw "$game/A10KW/osm.net.xml" 0.3 26 "$game/A10KW/osm.poly.xml"
echo "made $out/{drt,rilsa3} (validation) and $out/{ingolstadt,fokr_bs,bs,a10kw} (test)"

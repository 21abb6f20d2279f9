"""In-process SUMO for coid-sim: a thin shim over libsumo.

The Rust bridge (src/bridge.rs) loads this file into the embedded
interpreter. One call per simulation step returns every vehicle and person
as plain tuples, so the per-object cost stays that of a plain Python libsumo
loop. Per-type attributes (class, size, colour) are read once and cached; a
road user's own colour (the demand's `color` on a vehicle, flow or person)
is read once per id and kept while it is on the road. Its colour is its own
if the demand gives one, else its type's; SUMO reports "none" as its
default yellow (255, 255, 0), which the Rust side may replace.
Positions and angles are returned exactly as SUMO reports them (front
bumper, navigational degrees); the Rust side converts them.
"""

import os

import libsumo

_type_cache = {}
_own_colours = {}
_DEFAULT_COLOUR = (255, 255, 0)


def start(args, stderr_path):
    """Starts SUMO with a full command line (args[0] is the binary name).

    While SUMO loads, the process's standard error goes to `stderr_path`:
    SUMO prints its load errors there (libsumo's exception then only says
    "Process Error"), and the caller reports them in one line instead.
    """
    _type_cache.clear()
    _own_colours.clear()
    saved = os.dup(2)
    capture = os.open(stderr_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.dup2(capture, 2)
        libsumo.start(list(args))
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(capture)
    return libsumo.simulation.getDeltaT()


def close():
    libsumo.close()


def junction_ids():
    return list(libsumo.junction.getIDList())


def junction_position(junction_id):
    x, y = libsumo.junction.getPosition(junction_id)
    return (float(x), float(y))


def polygons():
    """All polygons as (id, type, [(x, y), ...])."""
    poly = libsumo.polygon
    return [(p, poly.getType(p), [(float(x), float(y)) for x, y in poly.getShape(p)])
            for p in poly.getIDList()]


def lanes():
    """Every lane (internal ones too) as (id, width, [(x, y), ...])."""
    lane = libsumo.lane
    return [(l, float(lane.getWidth(l)), [(float(x), float(y)) for x, y in lane.getShape(l)])
            for l in lane.getIDList()]


def _type_info(type_id, is_person):
    info = _type_cache.get(type_id)
    if info is None:
        vt = libsumo.vehicletype
        vclass = "pedestrian" if is_person else vt.getVehicleClass(type_id)
        r, g, b, _a = vt.getColor(type_id)
        info = (vclass, float(vt.getLength(type_id)), float(vt.getWidth(type_id)),
                float(vt.getHeight(type_id)), (int(r), int(g), int(b)))
        _type_cache[type_id] = info
    return info


def _colour(own, uid, get_colour, type_colour):
    """The road user's own colour if the demand gives it one, else its type's."""
    c = own.get(uid)
    if c is None:
        r, g, b, _a = get_colour(uid)
        c = (int(r), int(g), int(b))
    _own_colours[uid] = c
    return type_colour if c == _DEFAULT_COLOUR else c


def step():
    """Advances one step; returns (time_s, min_expected, rows).

    rows: [(id, vclass, (x, y, angle_nav_deg, speed, length, width, height), (r, g, b), type_id)]
    """
    global _own_colours
    libsumo.simulationStep()
    rows = []
    own, _own_colours = _own_colours, {}  # keeps only the road users still on the road
    veh = libsumo.vehicle
    get_pos, get_angle, get_speed, get_type = veh.getPosition, veh.getAngle, veh.getSpeed, veh.getTypeID
    for vid in veh.getIDList():
        type_id = get_type(vid)
        vclass, length, width, height, colour = _type_info(type_id, False)
        colour = _colour(own, vid, veh.getColor, colour)
        x, y = get_pos(vid)
        rows.append((vid, vclass, (x, y, get_angle(vid), get_speed(vid), length, width, height), colour,
                     type_id))
    per = libsumo.person
    get_pos, get_angle, get_speed, get_type = per.getPosition, per.getAngle, per.getSpeed, per.getTypeID
    for pid in per.getIDList():
        type_id = get_type(pid)
        vclass, length, width, height, colour = _type_info(type_id, True)
        colour = _colour(own, pid, per.getColor, colour)
        x, y = get_pos(pid)
        rows.append((pid, vclass, (x, y, get_angle(pid), get_speed(pid), length, width, height), colour,
                     type_id))
    sim = libsumo.simulation
    return (sim.getTime(), sim.getMinExpectedNumber(), rows)

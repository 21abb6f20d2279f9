"""Baseline for the bridge cost: a plain Python libsumo loop on the same
scenario, seed and duration, reading the same attributes per road user as
the bridge does (position, angle, speed, type; per-type attributes cached).

    .venv/bin/python bridge/bench_plain.py [sumocfg] [seed] [end_s]

Prints ms per step for SUMO's step alone, for step + reads, and the read
cost per road user. Compare with the "SUMO bridge ... ms/step" figure that
`coid run` prints (the bridge's time includes conversion into Rust structs).
"""

import sys
import time

import libsumo

cfg = sys.argv[1] if len(sys.argv) > 1 else "sumo_nets/intersection/intersection.sumocfg"
seed = sys.argv[2] if len(sys.argv) > 2 else "1"
end = float(sys.argv[3]) if len(sys.argv) > 3 else 130.0
args = ["sumo", "-c", cfg, "--seed", seed, "--end", str(end), "--no-step-log", "true",
        "--no-warnings", "true", "--duration-log.disable", "true"]


def run(read):
    libsumo.start(args)
    cache = {}
    steps = objects = 0
    t0 = time.perf_counter()
    while libsumo.simulation.getTime() + 1e-6 < end:
        libsumo.simulationStep()
        steps += 1
        if not read:
            continue
        rows = []
        for dom, is_person in ((libsumo.vehicle, False), (libsumo.person, True)):
            for oid in dom.getIDList():
                tid = dom.getTypeID(oid)
                info = cache.get(tid)
                if info is None:
                    vt = libsumo.vehicletype
                    info = ("pedestrian" if is_person else vt.getVehicleClass(tid), vt.getLength(tid),
                            vt.getWidth(tid), vt.getHeight(tid), vt.getColor(tid))
                    cache[tid] = info
                x, y = dom.getPosition(oid)
                rows.append((oid, info[0], (x, y, dom.getAngle(oid), dom.getSpeed(oid)) + info[1:4], info[4]))
                objects += 1
    elapsed = time.perf_counter() - t0
    libsumo.close()
    return elapsed, steps, objects


step_only, steps, _ = run(False)
with_reads, steps, objects = run(True)
print(f"steps {steps}, road users read {objects} ({objects / steps:.1f} per step)")
print(f"SUMO step alone:        {step_only / steps * 1e3:.3f} ms/step")
print(f"step + plain reads:     {with_reads / steps * 1e3:.3f} ms/step")
print(f"plain reads per object: {(with_reads - step_only) / objects * 1e6:.2f} us")

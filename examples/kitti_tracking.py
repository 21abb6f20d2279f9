"""Detections from elsewhere into a coid dataset: two vehicles' detection
files in the style of KITTI tracking labels, one per vehicle, written
through coid_sim.DatasetWriter (pip install coid-sim).

    python examples/kitti_tracking.py --labels cv0.txt cv1.txt --poses cv0.poses cv1.poses --out results/kitti
    python examples/kitti_tracking.py --labels cv0.txt cv1.txt --shared --out results/kitti-shared
    coid dataset results/kitti

A label file holds one detection per line, KITTI tracking's columns:

    frame track_id type truncated occluded alpha left top right bottom height width length x y z rotation_y

with (x, y, z) the object's centre in the vehicle's camera frame (x right,
y down, z forward, metres; the camera at the vehicle's centre) and its
size (height, width, length); the box's heading is left out (coid's nodes
carry a heading only with a speed, which the labels lack). The track ids are the
ground truth: one object has one id in both vehicles' files (a detection
of nothing: an id the other file does not use). `DontCare` lines are
left out; Car, Van, Truck, Pedestrian, Person_sitting, Cyclist and Tram
become coid's classes. Every frame in which both vehicles detect
something is an instance.

A poses file holds each frame's GNSS pose of the vehicle, `frame x y
heading` (world metres, radians counter-clockwise from the world x axis),
reported at one pose-noise level (--level, with the sigmas the receiver
claims). With --shared the detections' (x, z) are already in a frame
both vehicles share (a map's, say, x right and z forward of its origin),
as data from infrastructure or a fusion stack often is: each vehicle then
reports the identity pose, so that the shared frame is every body frame
(docs/data-from-elsewhere.md).
"""

import argparse
import math
from pathlib import Path

import numpy as np

import coid_sim

CLASSES = {
    "Car": "car",
    "Van": "van",
    "Truck": "truck",
    "Pedestrian": "pedestrian",
    "Person_sitting": "pedestrian",
    "Cyclist": "bicycle",
    "Tram": "bus",
}


def read_labels(path):
    """Frame -> list of (track id, class, body x, body y, (l, w, h))."""
    frames = {}
    for k, line in enumerate(Path(path).read_text().splitlines()):
        f = line.split()
        if not f:
            continue
        if len(f) < 17:
            raise SystemExit(f"{path}:{k + 1}: {len(f)} columns, KITTI tracking labels have 17")
        if f[2] == "DontCare":
            continue
        if f[2] not in CLASSES:
            raise SystemExit(f"{path}:{k + 1}: unknown type {f[2]!r} (expected one of: {', '.join(CLASSES)}, DontCare)")
        h, w, l, x, _y, z = (float(v) for v in f[10:16])
        # Camera (x right, z forward) to body (x forward, y left).
        frames.setdefault(int(f[0]), []).append((f[1], CLASSES[f[2]], z, -x, (l, w, h)))
    return frames


def read_poses(path):
    """Frame -> (x, y, heading) in the world."""
    poses = {}
    for k, line in enumerate(Path(path).read_text().splitlines()):
        f = line.split()
        if f:
            if len(f) != 4:
                raise SystemExit(f"{path}:{k + 1}: expected 'frame x y heading'")
            poses[int(f[0])] = tuple(float(v) for v in f[1:])
    return poses


def side(vehicle, detections, shared):
    """One vehicle's nodes as coid_sim.Side."""
    n = len(detections)
    xy = np.asarray([(d[2], d[3]) for d in detections], dtype=np.float64).reshape(n, 2)
    return coid_sim.Side(
        id=vehicle,
        xy_m=xy,
        classes=np.asarray([d[1] for d in detections], dtype=object),
        sender=np.zeros(n, dtype=bool),
        object_id=np.asarray([f"track-{d[0]}" for d in detections], dtype=object),
        size_m=np.asarray([d[4] for d in detections], dtype=np.float64).reshape(n, 3),
        world_m=xy.copy() if shared else None,
    )


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--labels", nargs=2, required=True, metavar="FILE", help="each vehicle's label file (its name: the file's stem)")
    p.add_argument("--poses", nargs=2, metavar="FILE", help="each vehicle's GNSS poses (not with --shared)")
    p.add_argument("--shared", action="store_true", help="the detections are in a frame both vehicles share")
    p.add_argument("--level", default="gps", help="the pose-noise level's name [gps]")
    p.add_argument("--position-sigma", type=float, default=1.2, help="the position accuracy the receivers claim, m [1.2]")
    p.add_argument("--heading-sigma-deg", type=float, default=0.2, help="the heading accuracy, deg [0.2]")
    p.add_argument("--frame-period", type=float, default=0.1, help="seconds between frames [0.1: KITTI's 10 Hz]")
    p.add_argument("--split", default="test", help="the run's split [test]")
    p.add_argument("--out", required=True, help="the dataset folder to write")
    p.add_argument("--force", action="store_true", help="replace a dataset coid wrote there")
    a = p.parse_args()
    if a.shared == bool(a.poses):
        raise SystemExit("give --poses (each vehicle's GNSS poses) or --shared, one of them")
    vehicles = sorted(zip((Path(f).stem for f in a.labels), a.labels, a.poses or (None, None)))
    if vehicles[0][0] == vehicles[1][0]:
        raise SystemExit(f"both label files are named {vehicles[0][0]!r}: the vehicles need names of their own")
    labels = [read_labels(v[1]) for v in vehicles]
    poses = None if a.shared else [read_poses(v[2]) for v in vehicles]
    writer = coid_sim.DatasetWriter()
    run = writer.add_run(a.split, f"kitti/{Path(a.labels[0]).parent.name or 'labels'}")
    sigma = math.radians(a.heading_sigma_deg)
    for frame in sorted(labels[0].keys() & labels[1].keys()):
        if poses is None:
            reported = (coid_sim.writer.IDENTITY, coid_sim.writer.IDENTITY)
        else:
            missing = [v[2] for v, p in zip(vehicles, poses) if frame not in p]
            if missing:
                raise SystemExit(f"{missing[0]} has no pose of frame {frame}")
            reported = (poses[0][frame], poses[1][frame])
        level = coid_sim.Level(a.level, a.position_sigma, (sigma, sigma), reported)
        writer.add_instance(
            run,
            step=frame,
            time_s=frame * a.frame_period,
            first=side(vehicles[0][0], labels[0][frame], a.shared),
            second=side(vehicles[1][0], labels[1][frame], a.shared),
            levels=[level],
        )
    ds = writer.write(a.out, force=a.force)
    print(f"{ds.path}: {ds.runs['n_instances'].sum()} instances of {vehicles[0][0]} and {vehicles[1][0]}")


if __name__ == "__main__":
    main()

"""Write docs/markers.png: the markers of three grasps decided by the core, as RViz shows them.

One force-closure grasp, one rejected by the filter and one found not force closure by
the exact test, on a built-in object. Separating-wrench arrows are drawn where the
core's result has a ``separating_wrench`` (issue 9); without it there are none.

    .venv/bin/python scripts/markers_png.py [--out docs/markers.png] [--object box]
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.marker_render import render_marker_arrays
from grasp_fc_ros.markers import STATUS_LABELS, grasp_markers
from grasp_fc_ros.objects import OBJECT_NAMES, make_object, sample_grasps

SHOWN = (Status.FORCE_CLOSURE, Status.FILTERED_OUT, Status.NOT_FORCE_CLOSURE)
MU = math.tan(math.radians(20.0))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/markers.png")
    parser.add_argument("--object", default="box", choices=OBJECT_NAMES)
    parser.add_argument("--fingers", type=int, default=4)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)

    surface = make_object(args.object, n_points=2000)
    positions, normals = sample_grasps(surface, 2000, args.fingers,
                                       np.random.default_rng(args.seed))
    result = check_force_closure(positions, normals, MU)
    wrenches = getattr(result, "separating_wrench", None)
    arrays, titles = [], []
    for status in SHOWN:
        found = np.flatnonzero(result.status == status)
        if not found.size:
            print(f"no {status.name} grasp among 2000; try another --seed", file=sys.stderr)
            return 1
        k = int(found[0])
        wrench = None
        if wrenches is not None and np.isfinite(wrenches[k]).all():
            wrench = wrenches[k]
        arrays.append(grasp_markers(positions[k], normals[k], MU, status, query_id=k,
                                    frame_id=args.object, margin=float(result.margin[k]),
                                    separating_wrench=wrench))
        titles.append(f"{STATUS_LABELS[status]} (grasp {k})")
    path = render_marker_arrays(arrays, args.out, titles=titles,
                                clouds=[surface.points[::4]] * len(arrays))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

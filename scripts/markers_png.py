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

from grasp_fc_ros.core import check_force_closure
from grasp_fc_ros.markers.render import EXAMPLE_STATUSES, render_verdict_examples
from grasp_fc_ros.objects import OBJECT_NAMES, make_object, sample_grasps

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
    result = check_force_closure(positions, normals, MU, certificates=True)
    chosen = render_verdict_examples(
        args.out, positions, normals, MU, result.status, result.margin,
        separating_wrench=result.separating_wrench,
        frame_id=args.object, cloud=surface.points[::4])
    if len(chosen) < len(EXAMPLE_STATUSES):
        print("not every verdict occurs among 2000 grasps; try another --seed",
              file=sys.stderr)
        return 1
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

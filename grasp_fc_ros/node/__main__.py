"""``python -m grasp_fc_ros.node``: the same as ``grasp-fc-node``."""

import sys

from grasp_fc_ros.node.cli import main

sys.exit(main())

"""grasp-fc-demo end to end: the action's progress bar, where markers go, the PNG."""

import re
import subprocess
import sys
from pathlib import Path

import ros_fixtures  # noqa: F401 - sets this run's own ROS_DOMAIN_ID in os.environ


def test_demo_labels_through_the_action_and_writes_the_markers_png(tmp_path):
    demo = Path(sys.executable).with_name("grasp-fc-demo")
    png = tmp_path / "out" / "markers.png"
    done = subprocess.run([str(demo), "--grasps", "400", "--markers-png", str(png)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    # The 20 single queries first, then 380 grasps through label_grasps with a bar.
    assert re.search(r"label_grasps: 100%\|.*\| 380/380", done.stderr), done.stderr
    assert re.search(r"^  queries\s+400$", done.stdout, re.M), done.stdout
    # The bar's total and the table's differ by the single queries, and both say so.
    assert "the first 20 as single queries on contacts, the other 380 as a label_grasps " \
        "job (its progress bar):" in done.stdout
    assert re.search(r"^  single queries \(contacts\)\s+20$", done.stdout, re.M)
    assert re.search(r"^  label_grasps \(progress bar\)\s+380$", done.stdout, re.M)
    assert re.search(r"^markers: ", done.stdout, re.M)
    assert f"to {png}" in done.stdout
    data = png.read_bytes()
    assert data.startswith(b"\x89PNG\r\n\x1a\n") and len(data) > 10_000

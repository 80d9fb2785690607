"""The certificates benchmark runs end to end and prints a line per setting (tiny sizes;
timings are not asserted)."""

import ros_fixtures  # noqa: F401 - sets this run's own ROS_DOMAIN_ID in os.environ
from bench_scripts import run_benchmark


def test_certificates_benchmark_prints_every_setting_without_losing_queries():
    out = run_benchmark(
        "bench_certificates", "--batches", "1", "--batch-size", "40", "--queries", "50")
    lines = out.splitlines()
    for tag in ("off", "certificates", "certificates+min_friction"):
        line = next(x for x in lines if x.strip().startswith(tag + " "))
        assert "B/grasp" in line and "INCOMPLETE" not in line and "LOST" not in line

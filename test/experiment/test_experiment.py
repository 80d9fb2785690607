"""Runs the experiment's --quick version once and checks its outputs, and tests the peer."""

import csv
import math

import numpy as np
import pytest

pytest.importorskip("matplotlib")
pytest.importorskip("scipy")

from grasp_fc_ros.experiment import cli, epsilon_study, report, robustness_study  # noqa: E402
from grasp_fc_ros.experiment.linearized_peer import linearized_force_closure, pyramid_edges  # noqa: E402
from grasp_fc_ros.objects import make_object  # noqa: E402

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("experiment")
    assert cli.main(["--quick", "--out", str(out)]) == 0
    return out


def _rows(path):
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def test_quick_run_writes_report_csv_and_plots(quick_run):
    for name in (report.REPORT_MD, report.RESULTS_CSV, report.FINGERS_CSV,
                 report.PEER_SIDES_CSV, report.ROBUSTNESS_CSV, *report.PLOTS.values()):
        assert (quick_run / name).stat().st_size > 0, name
    for name in report.PLOTS.values():
        assert (quick_run / name).read_bytes()[:8] == PNG_MAGIC, name
    text = (quick_run / report.REPORT_MD).read_text()
    for heading in ("Table I", "Table II", "Per-query cost", "linearized peer",
                    "Ferrari-Canny epsilon", "Robustness: radii, probability"):
        assert heading in text


def test_quick_robustness_rows_are_consistent(quick_run):
    rows = _rows(quick_run / report.ROBUSTNESS_CSV)
    assert [r["object"] for r in rows] == [*cli.DEFAULT_OBJECTS, "all"]
    for r in rows[:-1]:
        assert int(r["grasps"]) == int(r["label_grasps"]) == cli.QUICK["robustness_grasps"]
        assert 0 <= int(r["label_differ"]) <= int(r["label_grasps"])
        assert 0 <= int(r["top_epsilon_bottom_probability"]) <= int(r["top_epsilon"])
        assert int(r["top_epsilon"]) <= max(1, int(r["force_closure"]))
    for key in ("grasps", "force_closure", "top_epsilon", "label_differ"):
        assert int(rows[-1][key]) == sum(int(r[key]) for r in rows[:-1]), key


def test_robustness_only_writes_its_report(tmp_path):
    assert cli.main(["--quick", "--robustness-only", "--objects", "box", "ellipsoid",
                     "--out", str(tmp_path)]) == 0
    for name in (report.ROBUSTNESS_REPORT_MD, report.ROBUSTNESS_CSV,
                 report.PLOTS["robustness"]):
        assert (tmp_path / name).stat().st_size > 0, name
    assert "Spearman" in (tmp_path / report.ROBUSTNESS_REPORT_MD).read_text()


def test_robustness_study_ranks_and_counts_by_hand():
    """Spearman's matrix is symmetric with a unit diagonal; the top-by-epsilon count and
    the label flips count what they say on a hand-made object."""
    measures = {name: np.arange(10.0) for name in robustness_study.MEASURES}
    measures["probability"] = np.arange(10.0)[::-1]           # the reverse order
    made = robustness_study.ObjectRobustness(
        "made", 12, measures, few=np.array([0.6, 0.4, 0.52, 0.0] * 3),
        many=np.array([0.4, 0.4, 0.55, 0.0] * 3))
    matrix = robustness_study.correlations([made])
    np.testing.assert_allclose(matrix, matrix.T)
    np.testing.assert_allclose(np.diag(matrix), 1.0)
    assert matrix[-1, 1] == pytest.approx(-1.0)
    # top 10 % of 10 by epsilon: the grasp with epsilon 9, whose probability is lowest
    assert made.top_epsilon_in_bottom_probability() == (1, 1)
    assert made.label_flips() == (3, 12)


def test_quick_run_numbers_are_consistent(quick_run):
    rows = _rows(quick_run / report.RESULTS_CSV)
    assert [r["object"] for r in rows] == list(cli.DEFAULT_OBJECTS)
    for r in rows:
        grasps = int(r["grasps"])
        assert grasps == cli.QUICK["grasps"]
        fc = int(r["fc_unfiltered"])
        # soundness: the filter never changes a verdict, with either choice of origins
        assert int(r["fc_filtered"]) == fc and int(r["fc_filtered_all"]) == fc
        assert int(r["unsound"]) == 0 and int(r["unsound_all"]) == 0
        assert int(r["verdict_mismatches"]) == 0 and int(r["verdict_mismatches_all"]) == 0
        for suffix in ("", "_all"):
            passed = int(r["passed_filter" + suffix])
            false_pos = int(r["false_positives" + suffix])
            assert passed == fc + false_pos
            specificity = (grasps - passed) / (grasps - fc)
            assert math.isclose(float(r["specificity" + suffix]), specificity, abs_tol=1e-4)
        # "all" origins include the seed ones, so it rejects at least as much
        assert int(r["passed_filter_all"]) <= int(r["passed_filter"])
        assert math.isclose(float(r["speedup"]),
                            float(r["unfiltered_s"]) / float(r["filtered_s"]), rel_tol=0.01)
        assert int(r["peer_grasps"]) == cli.QUICK["peer_grasps"]


def test_quick_run_sweeps_cover_requested_ranges(quick_run):
    fingers = _rows(quick_run / report.FINGERS_CSV)
    assert [int(r["fingers"]) for r in fingers] == list(range(cli.FINGER_RANGE[0],
                                                              cli.FINGER_RANGE[1] + 1))
    sides = _rows(quick_run / report.PEER_SIDES_CSV)
    assert [int(r["sides"]) for r in sides] == list(cli.DEFAULT_SIDES_SWEEP)
    # an inscribed pyramid never turns a non-force-closure grasp into force closure
    assert all(int(r["false_fc"]) == 0 for r in sides)


def test_cli_rejects_bad_arguments(tmp_path):
    with pytest.raises(SystemExit):
        cli.main(["--quick", "--objects", "teapot", "--out", str(tmp_path)])
    with pytest.raises(SystemExit):
        cli.main(["--quick", "--fingers", "1", "--out", str(tmp_path)])
    with pytest.raises(SystemExit, match="no such file"):
        cli.main(["--quick", "--objects", "--mesh", str(tmp_path / "nope.stl"),
                  "--out", str(tmp_path)])


def test_pyramid_edges_lie_on_the_cone():
    normals = np.array([[0.0, 0.0, 2.0], [1.0, 1.0, 0.0]])
    mu = 0.3
    edges = pyramid_edges(normals, mu, sides=8)
    assert edges.shape == (2, 8, 3)
    unit_normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    cosines = np.einsum("nmk,nk->nm", edges, unit_normals)
    np.testing.assert_allclose(cosines, 1.0 / np.sqrt(1.0 + mu * mu))


def test_peer_on_textbook_grasps():
    # six contacts at the centres of a cube's faces, pushing inward: force closure
    # with friction; two opposite contacts alone never are (no torque about their axis)
    axes = np.vstack([np.eye(3), -np.eye(3)])
    positions, normals = axes, -axes
    assert linearized_force_closure(positions, normals, 0.5)
    assert not linearized_force_closure(positions[[0, 3]], normals[[0, 3]], 0.5)
    # all contacts pushing the same way: no force closure
    assert not linearized_force_closure(positions, np.tile([0.0, 0.0, 1.0], (6, 1)), 0.5)


def test_peer_never_accepts_what_the_exact_test_rejects():
    core = pytest.importorskip("grasp_fc_ros.core")
    surface = make_object("l_block", n_points=1000, seed=0)
    from grasp_fc_ros.objects import sample_grasps

    positions, normals = sample_grasps(surface, 60, 6, np.random.default_rng(5))
    mu = math.tan(math.radians(10.0))
    exact = core.check_force_closure(positions, normals, mu, use_filter=False).force_closure
    peer = linearized_force_closure(positions, normals, mu, sides=8)
    assert not np.any(peer & ~exact)
    assert exact.any() and peer.any()


def test_cli_adds_mesh_files_as_objects(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    path = tmp_path / "part.stl"
    trimesh.creation.icosphere(radius=0.05).export(path)
    args = cli.resolve_settings(cli.build_parser().parse_args(
        ["--quick", "--objects", "box", "--mesh", str(path), "--points", "300"]))
    surfaces = cli.load_objects(args)
    assert [s.name for s in surfaces] == ["box", "part"]
    assert all(len(s) == 300 for s in surfaces)


def test_quick_run_friction_labels(quick_run):
    rows = _rows(quick_run / report.FRICTION_LABELS_CSV)
    assert len(rows) == len(cli.DEFAULT_OBJECTS) * cli.QUICK["label_grasps"]
    mu_star = np.array([float(r["mu_star"]) for r in rows])
    certified = mu_star[~np.isnan(mu_star)]
    assert certified.size >= 0.9 * mu_star.size
    assert np.all(certified >= 0.0)
    text = (quick_run / report.REPORT_MD).read_text()
    assert "Grasp quality: minimum friction and soft fingers" in text


def test_quick_run_soft_sweep(quick_run):
    rows = _rows(quick_run / report.SOFT_SWEEP_CSV)
    by_grasps = {}
    for r in rows:
        key = (r["object"], int(r["fingers"]))
        by_grasps.setdefault(key, []).append((float(r["gamma_over_size"]),
                                              int(r["force_closure"])))
    assert len(by_grasps) == len(cli.DEFAULT_OBJECTS) * 3
    for (name, fingers), counts in by_grasps.items():
        counts.sort()
        assert counts[0][0] == 0.0
        if fingers == 2:
            assert counts[0][1] == 0, f"two hard fingers are never force closure ({name})"
        # a soft cone contains the hard one and grows with gamma: the same grasps can
        # only gain force closure as gamma grows
        fc = [count for _, count in counts]
        assert fc == sorted(fc), (name, fingers, counts)


def _check_epsilon_rows(rows, objects):
    edges = [int(e) for e in epsilon_study.EDGE_COUNTS]
    assert [(r["object"], int(r["edges"])) for r in rows] == [
        (name, e) for e in edges for name in [*objects, "all"]]
    for r in rows:
        fc, grasps = int(r["force_closure"]), int(r["grasps"])
        assert 0 <= fc <= grasps
        # the inscribed pyramid lies inside W: its Q1 never exceeds the certified bound
        assert int(r["above_upper"]) == 0
        assert int(r["pyramid_zero"]) <= fc
        assert int(r["flipped_pairs"]) + int(r["tied_pairs"]) <= int(r["ordered_pairs"])
        assert int(r["ordered_pairs"]) <= fc * (fc - 1) // 2
        if fc:
            errors = [float(r[k]) for k in ("median_error", "p90_error", "max_error")]
            assert 0.0 <= errors[0] <= errors[1] <= errors[2] <= 1.0
    total = next(r for r in rows if r["object"] == "all" and int(r["edges"]) == edges[0])
    assert int(total["grasps"]) == len(objects) * cli.QUICK["epsilon_grasps"]


def test_quick_run_compares_epsilon_with_the_pyramids(quick_run):
    _check_epsilon_rows(_rows(quick_run / report.EPSILON_CSV), list(cli.DEFAULT_OBJECTS))


def test_epsilon_only_run_writes_its_own_report(tmp_path):
    assert cli.main(["--quick", "--epsilon-only", "--objects", "box", "mug",
                     "--out", str(tmp_path)]) == 0
    _check_epsilon_rows(_rows(tmp_path / report.EPSILON_CSV), ["box", "mug"])
    assert (tmp_path / report.PLOTS["epsilon"]).read_bytes()[:8] == PNG_MAGIC
    text = (tmp_path / report.EPSILON_REPORT_MD).read_text()
    assert "Ferrari-Canny epsilon" in text and "Reproduce: `grasp-fc-experiment" in text
    assert not (tmp_path / report.RESULTS_CSV).exists()


def test_pyramid_q1_on_the_cube_faces():
    """Inscribed pyramids lie inside the cones: Q1 <= 1/sqrt(6), growing with the edges
    (the 4 edges are among the 8), and close to it with many edges."""
    axes = np.vstack([np.eye(3), -np.eye(3)])
    centre = np.zeros(3)
    q1 = {edges: epsilon_study.pyramid_q1(axes, -axes, 0.5, centre, 1.0, edges)
          for edges in (4, 8, 64)}
    exact = 1.0 / np.sqrt(6.0)
    assert 0 < q1[4] <= q1[8] <= q1[64] <= exact * (1 + 1e-12)
    assert q1[64] >= 0.99 * exact
    # a grasp that is not force closure (all normals alike) scores 0
    assert epsilon_study.pyramid_q1(axes, np.tile([0.0, 0, 1], (6, 1)), 0.5, centre, 1.0) == 0

"""RViz markers of one answered query: geometry, colours, ids, lifetime; the PNG renderer.

No DDS: markers are built and inspected as messages.
"""

from __future__ import annotations

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from visualization_msgs.msg import Marker

from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.markers.build import (
    CONE_ALPHA,
    CONES_ID,
    CONTACTS_ID,
    FORCE_ARROW_ID,
    STATUS_COLORS,
    TEXT_ID,
    TORQUE_ARROW_ID,
    WRENCH_FORCE_COLOR,
    cone_axes,
    delete_all_markers,
    friction_cone_rims,
    friction_cone_triangles,
    grasp_markers,
    marker_namespace,
    separating_arrows,
)

# The geometry is a few float operations per vertex: agreement to this is exact up to
# rounding for lengths and angles of order one.
GEOMETRY_TOL = 1e-9

FOUR = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], dtype=float)

finite = st.floats(-10, 10, allow_nan=False, allow_infinity=False)
vectors = arrays(float, (5, 3), elements=finite)
frictions = arrays(float, (5,), elements=st.floats(0.01, 5.0))


def _normals(raw):
    """Non-degenerate normals of any length from hypothesis' raw vectors."""
    return raw + np.where(np.linalg.norm(raw, axis=1, keepdims=True) < 1e-3, 1.0, 0.0)


def _angle(a, b):
    cos = np.sum(a * b, -1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.arccos(np.clip(cos, -1.0, 1.0))


@settings(max_examples=60, deadline=None)
@given(positions=vectors, raw_normals=vectors, mu=frictions,
       length=st.floats(1e-3, 1.0), segments=st.integers(3, 24))
def test_cone_apex_axis_half_angle_and_length(positions, raw_normals, mu, length, segments):
    normals = _normals(raw_normals)
    triangles = friction_cone_triangles(positions, normals, mu, length, segments)
    assert triangles.shape == (5, segments, 3, 3)
    # Every triangle starts at the apex: the contact.
    np.testing.assert_allclose(triangles[:, :, 0], np.repeat(positions[:, None], segments, 1))
    rims = friction_cone_rims(positions, normals, mu, length, segments)
    slant = rims - positions[:, None]
    np.testing.assert_allclose(np.linalg.norm(slant, axis=-1), length, rtol=GEOMETRY_TOL)
    # Opening away from the object (normals point into it), half-angle atan(mu).
    axis = -normals / np.linalg.norm(normals, axis=1, keepdims=True)
    np.testing.assert_allclose(_angle(slant, axis[:, None]),
                               np.repeat(np.arctan(mu)[:, None], segments, 1),
                               atol=1e-7)  # arccos near 0 loses half the digits
    # The rim's centre lies on the axis, at length cos(atan mu) from the apex.
    np.testing.assert_allclose(slant.mean(1), axis * (length * np.cos(np.arctan(mu)))[:, None],
                               atol=GEOMETRY_TOL * 10)
    # Consecutive triangles share an edge and close the surface.
    np.testing.assert_array_equal(triangles[:, :, 2], np.roll(triangles[:, :, 1], -1, axis=1))


def test_cone_axes_are_unit_and_point_out_of_the_object():
    axes = cone_axes(np.array([[0, 0, 3.0], [-2.0, 0, 0]]))
    np.testing.assert_allclose(axes, [[0, 0, -1], [1, 0, 0]])


def test_cone_rims_need_three_segments():
    with pytest.raises(ValueError, match="segments"):
        friction_cone_rims(FOUR, -FOUR, np.full(4, 0.5), 0.1, 2)


def _by_id(array):
    return {m.id: m for m in array.markers}


def _build(status=Status.FORCE_CLOSURE, **kwargs):
    options = dict(query_id=7, frame_id="palm", margin=0.0123)
    options.update(kwargs)
    return grasp_markers(FOUR, -FOUR, 0.5, status, **options)


def test_marker_types_frame_stamp_and_namespace():
    stamp = Time(sec=12, nanosec=34)
    markers = _by_id(_build(stamp=stamp, separating_wrench=[1.0, 0, 0, 0, 0, 1.0]))
    assert {i: m.type for i, m in markers.items()} == {
        CONTACTS_ID: Marker.SPHERE_LIST, CONES_ID: Marker.TRIANGLE_LIST,
        FORCE_ARROW_ID: Marker.ARROW, TORQUE_ARROW_ID: Marker.ARROW,
        TEXT_ID: Marker.TEXT_VIEW_FACING}
    for marker in markers.values():
        assert marker.header.frame_id == "palm"
        assert (marker.header.stamp.sec, marker.header.stamp.nanosec) == (12, 34)
        assert marker.ns == marker_namespace(7) == "grasp_7"
        assert marker.action == Marker.ADD
    contacts = markers[CONTACTS_ID]
    np.testing.assert_allclose([[p.x, p.y, p.z] for p in contacts.points], FOUR)
    assert len(markers[CONES_ID].points) == 4 * 12 * 3  # 12 triangles per cone by default


def test_points_equal_constructed_ones_and_serialize_alike():
    from geometry_msgs.msg import Point
    from rclpy.serialization import serialize_message

    [cones] = [m for m in _build().markers if m.id == CONES_ID]
    rebuilt = [Point(x=p.x, y=p.y, z=p.z) for p in cones.points]
    assert cones.points == rebuilt
    assert b"".join(map(serialize_message, cones.points)) == b"".join(
        map(serialize_message, rebuilt))
    cones.points[0].x = 1.5  # still behaves like a message point
    assert cones.points[0].x == 1.5 and cones.points[0] != rebuilt[0]


def test_triangle_list_holds_the_cone_geometry():
    cones = _by_id(grasp_markers(FOUR, -2 * FOUR, np.array([0.2, 0.4, 0.6, 0.8]), 0,
                                 query_id=1, frame_id="f", cone_length=0.05,
                                 cone_segments=8))[CONES_ID]
    points = np.array([[p.x, p.y, p.z] for p in cones.points])
    expected = friction_cone_triangles(FOUR, -2 * FOUR, np.array([0.2, 0.4, 0.6, 0.8]),
                                       0.05, 8)
    np.testing.assert_allclose(points, expected.reshape(-1, 3))


def test_namespaces_and_ids_unique_per_query():
    keys = [(m.ns, m.id) for q in (3, 4, 30)
            for m in _build(query_id=q, separating_wrench=np.ones(6)).markers]
    assert len(keys) == len(set(keys)) == 15


@pytest.mark.parametrize("status", list(Status))
def test_colours_follow_the_verdict(status):
    markers = _by_id(_build(status))
    rgba = STATUS_COLORS[status]
    for marker_id, alpha in ((CONTACTS_ID, rgba[3]), (CONES_ID, CONE_ALPHA), (TEXT_ID, rgba[3])):
        c = markers[marker_id].color
        assert (c.r, c.g, c.b, c.a) == pytest.approx((*rgba[:3], alpha))


def test_every_status_has_its_own_colour():
    assert len({rgba for rgba in STATUS_COLORS.values()}) == len(Status)


def test_text_names_query_verdict_and_margin():
    assert _by_id(_build(Status.NOT_FORCE_CLOSURE, margin=-0.25))[TEXT_ID].text == (
        "grasp 7: not force closure\nmargin -0.25")
    assert _by_id(_build(Status.FILTERED_OUT, margin=float("nan")))[TEXT_ID].text == (
        "grasp 7: rejected by the filter")
    text = _by_id(_build())[TEXT_ID]
    assert text.pose.position.z > FOUR[:, 2].max()  # above the grasp


@pytest.mark.parametrize("seconds, sec, nanosec", [(10.0, 10, 0), (2.5, 2, 500_000_000),
                                                   (0.0, 0, 0)])
def test_lifetime(seconds, sec, nanosec):
    for marker in _build(lifetime_s=seconds).markers:
        assert (marker.lifetime.sec, marker.lifetime.nanosec) == (sec, nanosec)


def test_delete_all():
    array = delete_all_markers("palm")
    [marker] = array.markers
    assert marker.action == Marker.DELETEALL and marker.header.frame_id == "palm"


def test_separating_arrows_refer_the_force_part_to_the_centroid():
    centroid = np.array([1.0, 0, 0])
    # A pure rotation about z through the origin moves the centroid along +y.
    arrows = separating_arrows(np.array([0, 0, 0, 0, 0, 1.0]), centroid, 0.5)
    np.testing.assert_allclose(arrows[FORCE_ARROW_ID], [centroid, centroid + [0, 0.5, 0]])
    np.testing.assert_allclose(arrows[TORQUE_ARROW_ID], [centroid, centroid + [0, 0, 0.5]])
    # About the centroid itself the same rotation has no force part: no force arrow.
    only_torque = separating_arrows(np.array([0, 0, 0, 0, 0, 1.0]), np.zeros(3), 0.5)
    assert set(only_torque) == {TORQUE_ARROW_ID}
    only_force = separating_arrows(np.array([0, 3.0, 0, 0, 0, 0]), centroid, 0.5)
    np.testing.assert_allclose(only_force[FORCE_ARROW_ID], [centroid, centroid + [0, 0.5, 0]])
    assert set(only_force) == {FORCE_ARROW_ID}


def test_no_arrows_without_a_separating_wrench():
    assert set(_by_id(_build(Status.NOT_FORCE_CLOSURE))) == {CONTACTS_ID, CONES_ID, TEXT_ID}


def test_invalid_query_draws_what_it_can():
    positions = FOUR.copy()
    normals = -FOUR.copy()
    positions[1] = np.nan      # no sphere, no cone
    normals[2] = 0.0           # sphere, no cone
    mu = np.array([0.5, 0.5, 0.5, np.inf])  # contact 3: no cone
    markers = _by_id(grasp_markers(positions, normals, mu, Status.INVALID_INPUT,
                                   query_id=2, frame_id="f", cone_segments=6))
    assert len(markers[CONTACTS_ID].points) == 3
    assert len(markers[CONES_ID].points) == 1 * 6 * 3
    assert markers[TEXT_ID].text == "grasp 2: invalid input"


@pytest.mark.parametrize("kwargs, match", [
    (dict(positions=np.zeros((4, 2))), "positions must have shape"),
    (dict(normals=np.ones((3, 3))), "normals must have the shape"),
    (dict(mu=np.ones(3)), "mu must be a scalar or have shape"),
    (dict(separating_wrench=np.ones(5)), "separating_wrench must have shape"),
    (dict(separating_wrench=[np.nan] * 6), "separating_wrench must be finite"),
    (dict(status=9), "9 is not a valid Status"),
    (dict(cone_length=float("inf")), "cone_length must be finite and > 0"),
    (dict(sphere_diameter=0.0), "sphere_diameter must be finite and > 0"),
    (dict(lifetime_s=-1.0), "lifetime_s must be finite and >= 0"),
])
def test_bad_input_is_named(kwargs, match):
    args = dict(positions=FOUR, normals=-FOUR, mu=0.5, status=Status.FORCE_CLOSURE)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        grasp_markers(**args, query_id=1, frame_id="f")


def test_markers_of_core_verdicts():
    top = np.array([[0.6, 0, 0.8], [-0.6, 0, 0.8], [0, 0.6, 0.8], [0, -0.6, 0.8]])
    result = check_force_closure(np.stack([FOUR, top]), -np.stack([FOUR, top]), mu=0.5)
    for k, positions in enumerate((FOUR, top)):
        array = grasp_markers(positions, -positions, 0.5, result.status[k], query_id=k,
                              frame_id="obj", margin=float(result.margin[k]))
        c = _by_id(array)[CONTACTS_ID].color
        assert (c.r, c.g, c.b) == pytest.approx(STATUS_COLORS[Status(result.status[k])][:3])
    assert Status(result.status[0]) == Status.FORCE_CLOSURE


def test_renderer_writes_a_png_showing_the_markers(tmp_path):
    from matplotlib.image import imread

    from grasp_fc_ros.markers.render import PANEL_SIZE_IN, render_marker_arrays

    unit_sizes = dict(cone_length=0.5, sphere_diameter=0.15, arrow_length=1.0,
                      text_height=0.1)  # the grasp spans 2 units
    arrays = [_build(Status.FORCE_CLOSURE, query_id=1, **unit_sizes),
              _build(Status.NOT_FORCE_CLOSURE, query_id=2,
                     separating_wrench=[0, 0, 1.0, 0, 0, 0], **unit_sizes)]
    arrays[1].markers.extend(delete_all_markers().markers)  # draws nothing, no error
    path = render_marker_arrays(arrays, tmp_path / "m.png", titles=["a", "b"],
                                clouds=[FOUR * 0.9, None], dpi=50)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = imread(path)
    assert image.shape[:2] == (round((PANEL_SIZE_IN + 0.4) * 50), round(2 * PANEL_SIZE_IN * 50))
    rgb = image[..., :3]
    for name, rgba in (("force closure", STATUS_COLORS[Status.FORCE_CLOSURE]),
                       ("not force closure", STATUS_COLORS[Status.NOT_FORCE_CLOSURE]),
                       ("the wrench arrow", WRENCH_FORCE_COLOR)):
        near = np.abs(rgb - np.array(rgba[:3])).max(-1) < 0.08
        assert near.sum() > 50, f"no pixels in the colour of {name}"


def test_renderer_refuses_what_it_cannot_draw(tmp_path):
    from grasp_fc_ros.markers.render import render_marker_arrays

    array = _build()
    array.markers[0].type = Marker.CYLINDER
    with pytest.raises(ValueError, match="grasp_7/0: type 3 is not drawn"):
        render_marker_arrays([array], tmp_path / "x.png")
    with pytest.raises(ValueError, match="titles has 2 entries for 1 panels"):
        render_marker_arrays([_build()], tmp_path / "x.png", titles=["a", "b"])


def test_verdict_examples_draw_the_first_grasp_of_each_verdict(tmp_path):
    from grasp_fc_ros.markers.render import render_verdict_examples

    top = np.array([[0.6, 0, 0.8], [-0.6, 0, 0.8], [0, 0.6, 0.8], [0, -0.6, 0.8]])
    positions = np.stack([top, FOUR, top, FOUR]) * 0.03
    status = np.array([Status.FILTERED_OUT, Status.FORCE_CLOSURE, Status.FILTERED_OUT,
                       Status.FORCE_CLOSURE])
    wrenches = np.full((4, 6), np.nan)
    wrenches[0] = [0, 0, 1.0, 0, 0, 0]
    chosen = render_verdict_examples(tmp_path / "v.png", positions, -positions, 0.5, status,
                                     np.array([np.nan, 0.1, np.nan, 0.2]),
                                     ids=np.array([10, 11, 12, 13]),
                                     separating_wrench=wrenches)
    assert chosen == [1, 0]  # force closure first, then filtered out; no NOT_FORCE_CLOSURE
    assert (tmp_path / "v.png").read_bytes()[:4] == b"\x89PNG"
    assert render_verdict_examples(tmp_path / "none.png", positions, -positions, 0.5,
                                   status, np.zeros(4),
                                   statuses=[Status.SOLVER_FAILURE]) == []
    assert not (tmp_path / "none.png").exists()

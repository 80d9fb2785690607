"""Tests of the built-in objects, surface loading and grasp sampling."""

import numpy as np
import pytest

from grasp_fc_ros.objects import (
    OBJECT_NAMES,
    ContactSurface,
    _inside,
    load_surface,
    make_object,
    sample_grasps,
)

# Step along the normal used to probe the solid; small enough that only points
# within ~1e-7 m of a sharp edge could step out through a neighbouring face.
PROBE_STEP = 1e-7
NON_CONVEX = ("torus", "l_block", "star_prism", "mug")


@pytest.mark.parametrize("name", OBJECT_NAMES)
def test_built_in_object_has_unit_inward_normals(name):
    surface = make_object(name, n_points=3000, seed=1)
    assert surface.points.shape == (3000, 3) and surface.normals.shape == (3000, 3)
    assert surface.points.dtype == np.float64
    np.testing.assert_allclose(np.linalg.norm(surface.normals, axis=1), 1.0, atol=1e-12)
    step = PROBE_STEP * surface.normals
    assert np.all(_inside(name, surface.points + step)), "a normal points outward"
    assert not np.any(_inside(name, surface.points - step)), "a point lies inside the solid"


@pytest.mark.parametrize("name", OBJECT_NAMES)
def test_built_in_object_is_centred_on_its_bounding_box(name):
    surface = make_object(name, n_points=4000, seed=0)
    centre = 0.5 * (surface.points.min(axis=0) + surface.points.max(axis=0))
    np.testing.assert_allclose(centre, 0.0, atol=2e-3)  # sampling misses the extremes by < 2 mm


def test_at_least_six_objects_including_non_convex():
    assert len(OBJECT_NAMES) >= 6
    assert set(NON_CONVEX) <= set(OBJECT_NAMES)


@pytest.mark.parametrize("name", NON_CONVEX)
def test_non_convex_object_is_not_convex(name):
    # a convex solid contains every midpoint of two of its boundary points
    surface = make_object(name, n_points=2000, seed=0)
    rng = np.random.default_rng(0)
    pairs = rng.integers(0, len(surface), size=(2000, 2))
    midpoints = surface.points[pairs].mean(axis=1)
    assert not np.all(_inside(name, midpoints))


def test_sampling_is_roughly_uniform_by_area():
    # the two 0.10 x 0.06 faces carry 48 % of the box's area
    surface = make_object("box", n_points=20000, seed=2)
    on_large_faces = np.abs(np.abs(surface.normals[:, 2]) - 1.0) < 1e-12
    area_share = 2 * 0.10 * 0.06 / (2 * (0.10 * 0.06 + 0.10 * 0.04 + 0.06 * 0.04))
    assert abs(on_large_faces.mean() - area_share) < 0.015


def test_make_object_is_reproducible_and_seeded():
    a = make_object("mug", n_points=500, seed=7)
    b = make_object("mug", n_points=500, seed=7)
    c = make_object("mug", n_points=500, seed=8)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.normals, b.normals)
    assert not np.array_equal(a.points, c.points)


def test_make_object_rejects_unknown_name():
    with pytest.raises(ValueError, match="unknown object 'teapot'"):
        make_object("teapot")


def test_contact_surface_validates_and_normalises():
    surface = ContactSurface("s", [[0.0, 0.0, 0.0]], [[0.0, 0.0, 2.0]])
    np.testing.assert_array_equal(surface.normals, [[0.0, 0.0, 1.0]])
    assert not surface.points.flags.writeable
    with pytest.raises(ValueError, match="normal of point 1 has zero length"):
        ContactSurface("s", np.zeros((2, 3)), [[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="differs from"):
        ContactSurface("s", np.zeros((2, 3)), np.ones((3, 3)))
    with pytest.raises(ValueError, match="finite"):
        ContactSurface("s", [[np.nan, 0.0, 0.0]], [[1.0, 0.0, 0.0]])


def test_sample_grasps_shapes_distinct_contacts_and_reproducible():
    surface = make_object("torus", n_points=400, seed=0)
    pos, nrm = sample_grasps(surface, 5000, 6, np.random.default_rng(3))
    assert pos.shape == (5000, 6, 3) and nrm.shape == (5000, 6, 3)
    # contacts come from the surface, paired with their own normals
    index = {tuple(p): i for i, p in enumerate(surface.points)}
    rows = np.array([[index[tuple(p)] for p in grasp] for grasp in pos[:200]])
    np.testing.assert_array_equal(surface.normals[rows], nrm[:200])
    # distinct within each grasp (with 400 points, ~3 % of raw draws repeat)
    ordered = np.sort(pos[:, :, 0], axis=1)
    assert np.all(np.diff(ordered, axis=1) != 0.0)
    again, _ = sample_grasps(surface, 5000, 6, np.random.default_rng(3))
    np.testing.assert_array_equal(pos, again)
    other, _ = sample_grasps(surface, 5000, 6, np.random.default_rng(4))
    assert not np.array_equal(pos, other)


def test_sample_grasps_all_points_when_n_equals_m():
    surface = make_object("box", n_points=5, seed=0)
    pos, _ = sample_grasps(surface, 50, 5, np.random.default_rng(0))
    for grasp in pos:
        assert sorted(map(tuple, grasp)) == sorted(map(tuple, surface.points))


def test_sample_grasps_rejects_too_many_fingers():
    surface = make_object("box", n_points=4, seed=0)
    with pytest.raises(ValueError, match="n_fingers"):
        sample_grasps(surface, 1, 5, np.random.default_rng(0))


# ---------------------------------------------------------------- files


def _box_mesh():
    trimesh = pytest.importorskip("trimesh")
    return trimesh.creation.box(extents=(0.2, 0.1, 0.06))


def _strictly_inside_box(points, half=(0.1, 0.05, 0.03)):
    return np.all(np.abs(points) < np.array(half), axis=1)


@pytest.mark.parametrize("suffix", [".obj", ".stl", ".ply"])
def test_mesh_round_trip_gives_inward_normals(tmp_path, suffix):
    path = tmp_path / f"block{suffix}"
    _box_mesh().export(path)
    surface = load_surface(path, n_points=800, seed=0)
    assert surface.name == "block" and surface.points.shape == (800, 3)
    # on the box surface (STL and PLY store float32 vertices)
    assert np.allclose(np.max(np.abs(surface.points) - [0.1, 0.05, 0.03], axis=1), 0.0,
                       atol=1e-7)
    assert _strictly_inside_box(surface.points + 1e-6 * surface.normals).all()
    again = load_surface(path, n_points=800, seed=0)
    np.testing.assert_array_equal(surface.points, again.points)


def test_inside_out_closed_mesh_is_flipped(tmp_path):
    mesh = _box_mesh()
    mesh.invert()
    path = tmp_path / "inverted.stl"
    mesh.export(path)
    surface = load_surface(path, n_points=300)
    assert _strictly_inside_box(surface.points + 1e-6 * surface.normals).all()


def test_npz_point_cloud_round_trip(tmp_path):
    original = make_object("l_block", n_points=300, seed=0)
    inward_path = tmp_path / "cloud_in.npz"
    np.savez(inward_path, points=original.points, normals=original.normals)
    loaded = load_surface(inward_path, cloud_normals="inward")
    np.testing.assert_array_equal(loaded.points, original.points)
    np.testing.assert_allclose(loaded.normals, original.normals)
    outward_path = tmp_path / "cloud_out.npz"
    np.savez(outward_path, points=original.points, normals=-original.normals)
    np.testing.assert_allclose(load_surface(outward_path).normals, original.normals)


def test_ply_point_cloud_round_trip(tmp_path):
    original = make_object("cylinder", n_points=50, seed=0)
    path = tmp_path / "scan.ply"
    header = ["ply", "format ascii 1.0", "element vertex 50"]
    header += [f"property double {axis}" for axis in ("x", "y", "z", "nx", "ny", "nz")]
    rows = [" ".join(f"{v:.17g}" for v in row)
            for row in np.hstack([original.points, -original.normals])]
    path.write_text("\n".join(header + ["end_header"] + rows) + "\n")
    loaded = load_surface(path)  # file normals are outward by default
    np.testing.assert_allclose(loaded.points, original.points)
    np.testing.assert_allclose(loaded.normals, original.normals)


def test_load_surface_errors_are_clear(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such file"):
        load_surface(tmp_path / "missing.obj")
    bad_suffix = tmp_path / "object.xyz"
    bad_suffix.write_text("0 0 0\n")
    with pytest.raises(ValueError, match="unsupported file type '.xyz'"):
        load_surface(bad_suffix)
    no_normals = tmp_path / "points_only.npz"
    np.savez(no_normals, points=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="missing array\\(s\\) normals"):
        load_surface(no_normals)
    ply_no_normals = tmp_path / "bare.ply"
    ply_no_normals.write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
                              "property float y\nproperty float z\nend_header\n0 0 0\n")
    with pytest.raises(ValueError, match="no normals"):
        load_surface(ply_no_normals)
    with pytest.raises(ValueError, match="cloud_normals"):
        load_surface(no_normals, cloud_normals="sideways")


def test_importing_objects_does_not_import_heavy_packages():
    import subprocess
    import sys

    code = ("import sys, grasp_fc_ros.objects; "
            "print(sorted(m for m in ('trimesh', 'scipy', 'matplotlib') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]"

"""grasp-fc-label without a cluster: lazy .npz and Parquet reading, chunk checks, output."""

import json
import re

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grasp_fc_ros.labelling import OutputConflict, Plan, cli, open_input
from grasp_fc_ros.labelling.npz_members import read_members
from grasp_fc_ros.labelling.output import Output
from grasp_fc_ros.labelling.runner import check_ranges
from grasp_fc_ros.labelling.tasks import label_chunk, validate_chunk
from grasp_fc_ros.objects import make_object, sample_grasps


def _grasps(n_grasps, n_fingers=4, seed=0):
    return sample_grasps(make_object("box", n_points=500), n_grasps, n_fingers,
                         np.random.default_rng(seed))


def _parquet(path, positions, normals, mu, nested=False, **extra):
    n_grasps, n = positions.shape[:2]
    if nested:
        def column(a):
            return pa.array(a.tolist(), pa.list_(pa.list_(pa.float64(), 3)))
    else:
        def column(a):
            return pa.FixedSizeListArray.from_arrays(pa.array(a.reshape(-1)), 3 * n)
    mu = np.asarray(mu, dtype=float)
    mu_column = (pa.array(np.broadcast_to(mu, (n_grasps,))) if mu.ndim < 2
                 else pa.array(mu.tolist(), pa.list_(pa.float64())))
    table = pa.table({"positions": column(positions), "normals": column(normals),
                      "mu": mu_column, **extra})
    pq.write_table(table, path, row_group_size=max(n_grasps // 3, 1))
    return path


@settings(max_examples=30, deadline=None)
@given(rows=st.integers(0, 40), width=st.integers(1, 5), compressed=st.booleans(),
       dtype=st.sampled_from([np.float64, np.float32, np.int64, np.uint64]),
       bounds=st.tuples(st.integers(-5, 45), st.integers(-5, 45)))
def test_npz_member_rows_equal_np_load(tmp_path_factory, rows, width, compressed, dtype,
                                       bounds):
    path = tmp_path_factory.mktemp("npz") / "a.npz"
    array = (np.arange(rows * width * 3).reshape(rows, width, 3) * 7 % 11).astype(dtype)
    (np.savez_compressed if compressed else np.savez)(path, a=array, s=np.float32(2.5))
    members = read_members(path)
    start, stop = bounds
    assert np.array_equal(members["a"].read(start, stop), array[start:stop])
    assert members["a"].read(start, stop).dtype == dtype
    assert members["s"].read() == np.float32(2.5)


def test_npz_source_chunk_and_default_ids(tmp_path):
    positions, normals = _grasps(30)
    mu = np.linspace(0.2, 0.6, 30)
    np.savez(tmp_path / "a.npz", positions=positions, normals=normals, mu=mu)
    source = open_input(tmp_path / "a.npz", id_offset=100)
    assert (source.n_grasps, source.n_contacts) == (30, 4)
    chunk = source.read(10, 20)
    assert np.array_equal(chunk.positions, positions[10:20])
    assert np.array_equal(chunk.mu[:, 0], mu[10:20])
    assert np.array_equal(chunk.ids, np.arange(110, 120))


@pytest.mark.parametrize("nested", [False, True])
def test_parquet_source_layouts(tmp_path, nested):
    positions, normals = _grasps(25)
    mu = np.random.default_rng(1).uniform(0.2, 0.8, (25, 4))
    path = _parquet(tmp_path / "g.parquet", positions, normals, mu, nested=nested,
                    ids=pa.array(np.arange(25, dtype=np.uint64) * 3))
    source = open_input(path)
    assert (source.n_grasps, source.n_contacts) == (25, 4)
    chunk = source.read(7, 19)  # spans row groups of 8 rows
    assert np.array_equal(chunk.positions, positions[7:19])
    assert np.array_equal(chunk.normals, normals[7:19])
    assert np.array_equal(chunk.mu, mu[7:19])
    assert np.array_equal(chunk.ids, np.arange(7, 19) * 3)


@settings(max_examples=40, deadline=None)
@given(sizes=st.lists(st.integers(0, 50), min_size=1, max_size=4),
       chunk_size=st.integers(1, 60))
def test_plan_chunks_partition_every_source(tmp_path_factory, sizes, chunk_size):
    folder = tmp_path_factory.mktemp("plan")
    sources = []
    for i, size in enumerate(sizes):
        positions, normals = np.zeros((size, 2, 3)), np.ones((size, 2, 3))
        np.savez(folder / f"{i}.npz", positions=positions, normals=normals, mu=0.5)
    plan = Plan.from_files([folder / f"{i}.npz" for i in range(len(sizes))],
                           chunk_size=chunk_size)
    for s, size in enumerate(sizes):
        rows = [r for c in plan.chunks if c.source == s for r in range(c.start, c.stop)]
        assert rows == list(range(size))
        sources.append(plan.sources[s].id_offset)
    assert sources == list(np.cumsum([0] + sizes[:-1]))
    assert all(0 < c.size <= chunk_size for c in plan.chunks)
    names = [c.part for c in plan.chunks]
    assert names == sorted(names) and len(set(names)) == len(names)


def test_plan_chunks_cover_every_row_once(tmp_path):
    for name, n_grasps in (("a", 23), ("b", 0), ("c", 5)):
        positions, normals = _grasps(n_grasps)
        np.savez(tmp_path / f"{name}.npz", positions=positions, normals=normals, mu=0.5)
    sources = [open_input(tmp_path / f"{name}.npz") for name in "abc"]
    chunks = Plan(sources, chunk_size=10).chunks
    assert [(c.source, c.start, c.stop) for c in chunks] == [
        (0, 0, 10), (0, 10, 20), (0, 20, 23), (2, 0, 5)]
    assert len({c.part for c in chunks}) == len(chunks)


def test_bad_values_named_by_file_row_and_id(tmp_path):
    positions, normals = _grasps(20)
    normals[13, 2] = 0.0
    np.savez(tmp_path / "bad.npz", positions=positions, normals=normals, mu=0.5,
             ids=np.arange(20, dtype=np.uint64) + 500)
    source = open_input(tmp_path / "bad.npz")
    assert validate_chunk(source, 0, 10) is None
    problem = validate_chunk(source, 10, 20)
    assert problem == (f"{source.path}: grasp 13 (id 513), contact 2: normal has zero length, "
                       "got (0, 0, 0)")


def test_negative_id_is_named(tmp_path):
    positions, normals = _grasps(6)
    ids = np.arange(6) + 40
    ids[3] = -1
    np.savez(tmp_path / "i.npz", positions=positions, normals=normals, mu=0.5, ids=ids)
    problem = validate_chunk(open_input(tmp_path / "i.npz"), 0, 6)
    assert problem == f"{tmp_path / 'i.npz'}: grasp 3: ids is negative (-1)"


def test_parquet_null_grasp_is_named(tmp_path):
    positions, normals = _grasps(6)
    table = pa.table({
        "positions": pa.array([row.reshape(-1).tolist() if i != 4 else None
                               for i, row in enumerate(positions)], pa.list_(pa.float64())),
        "normals": pa.array([row.reshape(-1).tolist() for row in normals]),
        "mu": pa.array(np.full(6, 0.5))})
    pq.write_table(table, tmp_path / "n.parquet")
    problem = validate_chunk(open_input(tmp_path / "n.parquet"), 0, 6)
    assert "n.parquet: grasp 4: positions has no value" in problem


def test_soft_grasps_are_labelled_with_their_torsional_friction(tmp_path):
    from grasp_fc_ros.core import check_force_closure, epsilon_quality

    # Two contacts on opposite sides of a 5 cm sphere: force closure only as soft fingers.
    direction = np.random.default_rng(4).normal(size=(30, 3))
    positions = 0.05 * np.stack([direction, -direction], axis=1) / np.linalg.norm(
        direction, axis=1)[:, None, None]
    normals = -positions
    torsional = np.full((30, 2), 0.01)
    torsional[::3] = 0.0  # some grasps hard
    np.savez(tmp_path / "t.npz", positions=positions, normals=normals, mu=0.5,
             torsional_friction=torsional)
    source = open_input(tmp_path / "t.npz")
    assert validate_chunk(source, 0, 30) is None
    table = label_chunk(source, 0, 30, "auto", "seed", quality_rtol=1e-3)
    soft = check_force_closure(positions, normals, 0.5, torsional_friction=torsional)
    hard = check_force_closure(positions, normals, 0.5)
    assert np.array_equal(table["status"].to_numpy(), soft.status)
    np.testing.assert_array_equal(soft.force_closure, torsional[:, 0] > 0)
    assert not hard.force_closure.any()
    epsilon = epsilon_quality(positions, normals, 0.5, torsional_friction=torsional)
    np.testing.assert_allclose(table["epsilon_upper"].to_numpy(), epsilon.upper,
                               rtol=1e-9, atol=1e-6)


def test_soft_fingers_are_refused_for_robustness_naming_grasp_and_contact(tmp_path):
    positions, normals = _grasps(8)
    torsional = np.zeros((8, 4))
    torsional[6, 2] = 0.004
    np.savez(tmp_path / "t.npz", positions=positions, normals=normals, mu=0.5,
             torsional_friction=torsional)
    source = open_input(tmp_path / "t.npz")
    assert validate_chunk(source, 0, 8) is None  # labelled as soft fingers
    assert validate_chunk(source, 0, 8, hard_only=True) == (
        f"{tmp_path / 't.npz'}: grasp 6 (id 6), contact 2: a soft finger (torsional "
        "friction 0.004): the robustness columns are for hard contacts "
        "(docs/robustness.md#limits)")
    assert validate_chunk(source, 0, 6, hard_only=True) is None  # hard (gamma 0) rows


def test_bad_torsional_friction_is_refused_naming_the_value(tmp_path):
    positions, normals = _grasps(8)
    torsional = np.zeros((8, 4))
    torsional[5, 3] = -0.01
    np.savez(tmp_path / "t.npz", positions=positions, normals=normals, mu=0.5,
             torsional_friction=torsional)
    problem = validate_chunk(open_input(tmp_path / "t.npz"), 0, 8)
    assert problem == (f"{tmp_path / 't.npz'}: grasp 5 (id 5), contact 3: torsional "
                       "friction must be >= 0 (0: a hard contact), got -0.01")


def test_label_chunk_equals_core(tmp_path):
    from grasp_fc_ros.core import check_force_closure

    positions, normals = _grasps(40, n_fingers=6)
    np.savez(tmp_path / "a.npz", positions=positions, normals=normals, mu=0.5)
    table = label_chunk(open_input(tmp_path / "a.npz"), 0, 40, "auto", "seed")
    expected = check_force_closure(positions, normals, 0.5)
    assert table.column_names == ["id", "force_closure", "status", "status_name", "margin"]
    assert np.array_equal(table["force_closure"].to_numpy(), expected.force_closure)
    assert np.array_equal(table["status"].to_numpy(), expected.status)
    assert np.array_equal(table["margin"].to_numpy(), expected.margin, equal_nan=True)
    names = table["status_name"].to_pylist()
    assert set(names) <= {"FORCE_CLOSURE", "NOT_FORCE_CLOSURE", "FILTERED_OUT"}
    assert len(set(names)) >= 2


def test_label_chunk_with_quality_adds_the_certified_epsilon(tmp_path):
    from grasp_fc_ros.core import epsilon_quality

    positions, normals = _grasps(30, n_fingers=6, seed=4)
    mu = np.random.default_rng(1).uniform(0.3, 0.8, 30)
    np.savez(tmp_path / "a.npz", positions=positions, normals=normals, mu=mu)
    table = label_chunk(open_input(tmp_path / "a.npz"), 0, 30, "auto", "seed",
                        quality_rtol=1e-4)
    assert table.column_names == ["id", "force_closure", "status", "status_name", "margin",
                                  "epsilon_lower", "epsilon_upper", "epsilon_direction"]
    expected = epsilon_quality(positions, normals, mu[:, None], rtol=1e-4)
    lower, upper = table["epsilon_lower"].to_numpy(), table["epsilon_upper"].to_numpy()
    direction = np.stack(table["epsilon_direction"].to_numpy(zero_copy_only=False))
    assert np.array_equal(lower, expected.lower) and np.array_equal(upper, expected.upper)
    assert np.array_equal(direction, expected.direction)
    fc = table["force_closure"].to_numpy()
    assert fc.any() and not fc.all()
    assert np.all((lower > 0) == fc) and np.all(upper[fc] - lower[fc] <= 1e-4 * upper[fc])
    # without --quality the table is as before
    plain = label_chunk(open_input(tmp_path / "a.npz"), 0, 30, "auto", "seed")
    assert plain.column_names == table.column_names[:5]


def test_label_chunk_with_robustness_adds_the_cores_columns(tmp_path):
    from grasp_fc_ros.core.robustness import (
        Holds,
        holds_under,
        probability_of_force_closure,
        robustness,
    )
    from grasp_fc_ros.labelling.robustness import Robustness

    positions, normals = _grasps(24, n_fingers=5, seed=6)
    mu = np.random.default_rng(2).uniform(0.4, 0.9, (24, 5))  # per contact
    ids = np.arange(24, dtype=np.uint64) * 7 + 1000
    np.savez(tmp_path / "a.npz", positions=positions, normals=normals, mu=mu, ids=ids)
    settings = Robustness(normal_error=0.03, friction_error=0.05, position_sigma=0.003,
                          normal_sigma=0.04, samples=40, confidence=0.9, seed=11)
    source = open_input(tmp_path / "a.npz")
    table = label_chunk(source, 0, 24, "auto", "seed", robustness=settings)
    assert table.schema.equals(Plan.from_files([tmp_path / "a.npz"],
                                               robustness=settings).schema)
    assert table.column_names[5:] == [
        "normal_angle", "position_radius", "friction_drop", "holds", "holds_name",
        "holds_bound", "probability_estimate", "probability_lower", "probability_upper",
        "probability_successes", "probability_undecided", "probability_normal_lower_bound"]
    radii = robustness(positions, normals, mu)
    for key in ("normal_angle", "position_radius", "friction_drop"):
        assert np.array_equal(table[key].to_numpy(), getattr(radii, key)), key
    holds = holds_under(positions, normals, mu, normal_error=0.03, friction_error=0.05)
    assert np.array_equal(table["holds"].to_numpy(), holds.status)
    assert table["holds_name"].to_pylist() == [Holds(h).name for h in holds.status]
    assert table["holds_bound"].to_pylist() == [str(b) for b in holds.bound]
    assert {"HOLDS", "BREAKS"} <= set(table["holds_name"].to_pylist())
    # Each grasp's noise comes from the run's seed and its id.
    probability = probability_of_force_closure(
        positions, normals, mu, position_sigma=0.003, normal_sigma=0.04, samples=40,
        confidence=0.9, seed=11, grasp_ids=ids)
    for key in ("estimate", "lower", "upper", "successes", "undecided"):
        assert np.array_equal(table[f"probability_{key}"].to_numpy(),
                              getattr(probability, key)), key
    estimate = table["probability_estimate"].to_numpy()
    assert 0 < estimate.mean() < 1 and len(np.unique(estimate)) > 3
    # Another chunking of the same grasps: the same columns, probability included.
    parts = [label_chunk(source, a, b, "auto", "seed", robustness=settings)
             for a, b in ((0, 5), (5, 6), (6, 24))]
    again = pa.concat_tables(parts)
    for key in table.column_names[5:]:
        if key != "probability_normal_lower_bound":
            assert again[key].equals(table[key]), key
    # Without holds or probability settings, the radii alone.
    radii_only = label_chunk(source, 0, 24, "auto", "seed", robustness=Robustness(seed=3))
    assert radii_only.column_names[5:] == ["normal_angle", "position_radius",
                                           "friction_drop"]


def test_quality_setting_in_schema_and_manifest(tmp_path):
    positions, normals = _grasps(10)
    np.savez(tmp_path / "a.npz", positions=positions, normals=normals, mu=0.5)
    plain = Plan.from_files([tmp_path / "a.npz"], chunk_size=5)
    quality = Plan.from_files([tmp_path / "a.npz"], chunk_size=5, quality_rtol=1e-3)
    assert "quality_rtol" not in plain.manifest()
    assert quality.manifest()["quality_rtol"] == 1e-3
    assert "epsilon_upper" not in plain.schema.names
    assert quality.schema.names[5:8] == ["epsilon_lower", "epsilon_upper",
                                         "epsilon_direction"]
    args = cli.build_parser().parse_args([str(tmp_path / "a.npz"), "--out", "o", "--quality",
                                          "--quality-rtol", "1e-5"])
    assert cli.make_plan(args).quality_rtol == 1e-5
    args = cli.build_parser().parse_args([str(tmp_path / "a.npz"), "--out", "o"])
    assert cli.make_plan(args).quality_rtol is None


def test_quality_usage_errors(tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        cli.main(["a.npz", "--out", str(tmp_path / "o"), "--quality", "--quality-rtol", "1.5"])
    assert stop.value.code == 2
    assert "--quality-rtol must be in [1e-9, 1), got 1.5" in capsys.readouterr().err
    assert "epsilon_direction" in cli.build_parser().format_help()


@pytest.mark.parametrize("out_name", ["labels", "labels.parquet"])
def test_cli_refusing_another_runs_output_names_the_users_option(tmp_path, capsys,
                                                                 monkeypatch, out_name):
    """A run with --quality on an output of a run without it exits 2 naming --quality,
    not the manifest's key quality_rtol."""
    import contextlib

    from grasp_fc_ros.labelling import runner
    from grasp_fc_ros.labelling.output import METADATA_KEY

    positions, normals = _grasps(10)
    np.savez(tmp_path / "a.npz", positions=positions, normals=normals, mu=0.5)
    out = tmp_path / out_name
    command = [str(tmp_path / "a.npz"), "--out", str(out), "--no-progress"]
    earlier = cli.make_plan(cli.build_parser().parse_args(command)).manifest()
    if out.suffix == ".parquet":
        pq.write_table(pa.table({"id": [0]}).replace_schema_metadata(
            {METADATA_KEY: json.dumps(earlier)}), out)
    else:
        Output(out, earlier).create()
    # The conflict is found before any task: no cluster is needed.
    monkeypatch.setattr(runner, "dask_client", lambda *_: contextlib.nullcontext())
    assert cli.main(command + ["--quality"]) == 2
    error = capsys.readouterr().err
    assert f"--out {out} holds labels of a run with other options (--quality/--quality-rtol)" \
        in error and "quality_rtol" not in error
    assert cli.main(command + ["--chunk-size", "7"]) == 2
    assert "(--chunk-size)" in capsys.readouterr().err


@pytest.mark.parametrize("arrays, message", [
    ({"positions": np.zeros((4, 3, 3)), "mu": 0.5}, "missing array(s) normals"),
    ({"positions": np.zeros((4, 3)), "normals": np.zeros((4, 3)), "mu": 0.5},
     "positions must have shape (N, n, 3), got (4, 3)"),
    ({"positions": np.zeros((4, 3, 3)), "normals": np.zeros((4, 3, 3)), "mu": np.ones(3)},
     "mu must be a scalar or have shape (4,) or (4, 3), got (3,)"),
    ({"positions": np.zeros((4, 3, 3)), "normals": np.zeros((4, 3, 3)), "mu": 0.5,
      "ids": np.zeros(4)}, "ids must be integers of shape (4,)"),
])
def test_cli_bad_file_exits_2_and_writes_nothing(tmp_path, capsys, arrays, message):
    good_p, good_n = _grasps(5)
    np.savez(tmp_path / "good.npz", positions=good_p, normals=good_n, mu=0.5)
    np.savez(tmp_path / "bad.npz", **arrays)
    out = tmp_path / "out"
    code = cli.main([str(tmp_path / "good.npz"), str(tmp_path / "bad.npz"), "--out", str(out)])
    assert code == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1
    assert str(tmp_path / "bad.npz") in error[0] and message in error[0]
    assert not out.exists()


def test_cli_usage_errors(tmp_path):
    with pytest.raises(SystemExit) as stop:
        cli.main(["--out", str(tmp_path / "o")])
    assert stop.value.code == 2
    with pytest.raises(SystemExit) as stop:
        cli.main(["--objects", "box", "--out", str(tmp_path / "o")])
    assert stop.value.code == 2


def test_output_refuses_another_runs_directory(tmp_path):
    Output(tmp_path / "o", {"chunk_size": 10}).create()
    assert Output(tmp_path / "o", {"chunk_size": 10}).existing_parts() == set()
    with pytest.raises(OutputConflict, match="differs in: chunk_size") as refused:
        Output(tmp_path / "o", {"chunk_size": 20}).existing_parts()
    assert refused.value.differing == ("chunk_size",)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "x.txt").write_text("x")
    with pytest.raises(OutputConflict, match="not a grasp-fc-label output"):
        Output(tmp_path / "other", {}).existing_parts()


def test_failed_part_write_leaves_nothing(tmp_path, monkeypatch):
    output = Output(tmp_path / "o", {"a": 1})
    output.create()

    def write_half_then_fail(table, where):
        open(where, "wb").write(b"PAR1 half a file")
        raise OSError("disk full")

    monkeypatch.setattr(pq, "write_table", write_half_then_fail)
    with pytest.raises(OSError, match="disk full"):
        output.write_part("part-00000-000000.parquet", pa.table({"x": [1]}))
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["_grasp_fc_label.json"]
    assert json.loads((tmp_path / "o" / "_grasp_fc_label.json").read_text()) == {"a": 1}


def test_object_grasps_are_the_same_whatever_the_chunks():
    from grasp_fc_ros.labelling import object_sources

    sources = object_sources(["box"], [], grasps_per_object=12, fingers=4, mu=0.5, seed=0,
                             points=200, draw_block=5)
    assert [c.size for c in Plan(sources, chunk_size=5).chunks] == [5, 5, 2]
    whole = [sources[0].read(c.start, c.stop) for c in Plan(sources, chunk_size=5).chunks]
    for chunk_size in (1, 3, 4, 7, 12):
        chunks = Plan(sources, chunk_size=chunk_size).chunks
        read = [sources[0].read(c.start, c.stop) for c in chunks]
        for key in ("positions", "normals", "ids"):
            assert np.array_equal(np.concatenate([getattr(r, key) for r in read]),
                                  np.concatenate([getattr(r, key) for r in whole])), key
    # The blocks are in the manifest where they are not the chunks.
    assert "draw_block" not in Plan(sources, chunk_size=5).manifest()
    assert Plan(sources, chunk_size=3).manifest()["draw_block"] == [5]


def test_chunk_size_follows_the_cost_of_the_columns(tmp_path):
    from grasp_fc_ros.labelling.robustness import Robustness
    from grasp_fc_ros.labelling.runner import (
        CHUNK_WORK,
        DEFAULT_CHUNK_SIZE,
        EPSILON_COST,
        RADII_COST,
        cost_per_grasp,
    )

    positions, normals = _grasps(10)
    np.savez(tmp_path / "a.npz", positions=positions, normals=normals, mu=0.5)

    def plan(**settings):
        return Plan.from_files([tmp_path / "a.npz"], **settings)

    assert plan().chunk_size == DEFAULT_CHUNK_SIZE
    assert plan(quality_rtol=1e-3).chunk_size == CHUNK_WORK // (1 + EPSILON_COST)
    radii = Robustness()
    assert plan(robustness=radii).chunk_size == CHUNK_WORK // (1 + RADII_COST)
    probability = Robustness(normal_sigma=0.05, samples=2000)
    assert cost_per_grasp(None, probability) == 1 + RADII_COST + 2000
    assert plan(robustness=probability).chunk_size == CHUNK_WORK // (1 + RADII_COST + 2000)
    assert plan(robustness=Robustness(normal_sigma=0.05, samples=10**8)).chunk_size == 1
    # Chunks of costly columns are checked in blocks of the verdicts' size.
    small = plan(robustness=probability, chunk_size=3)
    assert [(c.start, c.stop) for c in check_ranges(small.chunks)] == [(0, 10)]
    assert [(c.start, c.stop) for c in check_ranges(small.chunks, rows=6)] == [(0, 6),
                                                                               (6, 10)]
    assert [(c.start, c.stop) for c in check_ranges(small.chunks[1:2] + small.chunks[3:])
            ] == [(3, 6), (9, 10)]


def test_robustness_manifest_holds_what_changes_the_columns(tmp_path):
    from grasp_fc_ros.labelling.robustness import Robustness

    assert Robustness(samples=50, seed=3).manifest() == {}
    assert Robustness(normal_error=0.1).manifest() == {
        "position_error": 0.0, "normal_error": 0.1, "friction_error": 0.0}
    assert set(Robustness(friction_sigma=0.1).manifest()) == {
        "position_sigma", "normal_sigma", "friction_sigma", "samples", "confidence", "seed"}
    assert not Robustness(normal_sigma=0.1, samples=0).probability
    for bad, message in (({"normal_sigma": -1.0}, "normal_sigma must be finite and >= 0"),
                         ({"normal_error": 4.0}, "normal_error must be <= pi rad"),
                         ({"confidence": 1.0}, "confidence must be in (0, 1)")):
        with pytest.raises(ValueError, match=re.escape(message)):
            Robustness(**bad)


@pytest.mark.parametrize("first, second, named", [
    ([], ["--quality"], "--quality/--quality-rtol"),
    (["--quality"], ["--quality", "--quality-rtol", "1e-4"], "--quality/--quality-rtol"),
    (["--chunk-size", "4"], ["--chunk-size", "5"], "--chunk-size"),
    (["--chunk-size", "4"], ["--chunk-size", "5", "--quality"],
     "--quality/--quality-rtol; --chunk-size"),
    ([], ["--robustness"], "--robustness"),
    (["--robustness", "--normal-sigma", "0.1"],
     ["--robustness", "--normal-sigma", "0.1", "--samples", "50"], "--samples"),
    (["--robustness", "--normal-sigma", "0.1"],
     ["--robustness", "--normal-sigma", "0.1", "--seed", "2"], "--seed"),
    (["--robustness", "--normal-sigma", "0.1"], ["--robustness", "--normal-sigma", "0.2"],
     "--normal-sigma"),
    (["--robustness", "--normal-error", "0.1"],
     ["--robustness", "--normal-error", "0.1", "--position-error", "0.01"],
     "--position-error"),
])
def test_rerun_with_other_options_is_refused_naming_them(tmp_path, capsys, monkeypatch,
                                                         first, second, named):
    """Named as the user gives them; a default chunk size that follows the columns is not
    named when the columns differ."""
    import contextlib

    from grasp_fc_ros.labelling import runner
    from grasp_fc_ros.labelling.output import METADATA_KEY

    positions, normals = _grasps(10)
    np.savez(tmp_path / "a.npz", positions=positions, normals=normals, mu=0.5)
    monkeypatch.setattr(runner, "dask_client", lambda *_: contextlib.nullcontext())
    for out in (tmp_path / "dir", tmp_path / "one.parquet"):
        command = [str(tmp_path / "a.npz"), "--out", str(out), "--no-progress"]
        earlier = Output(out, cli.make_plan(cli.build_parser().parse_args(
            [*command, *first])).manifest())
        if out.suffix:  # a finished single file: its manifest is in its metadata
            pq.write_table(pa.table({"x": [1]}).replace_schema_metadata(
                {METADATA_KEY: earlier.text}), out)
        else:
            earlier.create()
        assert earlier.existing_parts() in (set(), None)  # the same options: resumes
        assert cli.main([*command, *second]) == 2
        assert f"other options ({named}); remove it" in capsys.readouterr().err


def test_robustness_options_need_robustness(tmp_path, capsys):
    for options, message in ((["--normal-sigma", "0.1"], "--normal-sigma needs --robustness"),
                             (["--samples", "10"], "--samples needs --robustness"),
                             (["--robustness", "--confidence", "1"],
                              "--confidence must be in (0, 1), got 1"),
                             (["--robustness", "--position-error", "-1"],
                              "must be finite and >= 0, got -1")):
        with pytest.raises(SystemExit) as stop:
            cli.main(["a.npz", "--out", str(tmp_path / "o"), *options])
        assert stop.value.code == 2
        assert message in capsys.readouterr().err
    args = cli.build_parser().parse_args(["a.npz", "--out", "o", "--robustness", "--seed", "4",
                                          "--normal-error", "0.1", "--friction-sigma", "0.2",
                                          "--samples", "30"])
    settings = cli.robustness_settings(args)
    assert (settings.normal_error, settings.friction_sigma, settings.samples,
            settings.seed) == (0.1, 0.2, 30, 4)
    assert settings.holds and settings.probability


def test_progress_line_has_rate_and_time_left():
    import io

    from grasp_fc_ros.labelling.runner import Progress, duration

    assert [duration(s) for s in (0, 59.4, 61, 3600, 86399, float("inf"))] == [
        "0:00", "0:59", "1:01", "1:00:00", "23:59:59", "?"]
    stream = io.StringIO()
    bar = Progress(1000, 4, stream=stream)
    bar.start -= 10.0  # 10 s ago
    for _ in range(4):
        bar.update(250)
    last = stream.getvalue().splitlines()[-1]
    assert "4/4 chunks, 1,000/1,000 grasps" in last and "grasps/s, 0:00 left" in last
    rate = float(last.split(" grasps/s")[0].rsplit(" ", 1)[1].replace(",", ""))
    assert 90 < rate <= 100


def test_labelling_imports_and_runs_without_ros(tmp_path):
    import subprocess
    import sys
    import textwrap

    positions, normals = _grasps(30)
    np.savez(tmp_path / "g.npz", positions=positions, normals=normals, mu=0.5)
    script = textwrap.dedent(f"""
        import sys
        class NoRos:
            def find_spec(self, name, path=None, target=None):
                top = name.split('.')[0]
                if top in ('rclpy', 'grasp_fc_msgs') or top.startswith('rcl'):
                    raise ImportError('ROS is not installed here: ' + name)
                return None
        sys.meta_path.insert(0, NoRos())
        from grasp_fc_ros.labelling import cli, open_input
        from grasp_fc_ros.labelling.tasks import label_chunk, validate_chunk
        source = open_input({str(tmp_path / "g.npz")!r})
        assert validate_chunk(source, 0, 30) is None
        assert label_chunk(source, 0, 30, True, "seed").num_rows == 30
        assert 'rclpy' not in sys.modules
        print('ok')
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().endswith("ok")

"""``grasp-fc-node`` as shipped: the console script, started as the README says, in a
user's environment (shipped_run.user_environment), with the shipped params file and
every feature switched on, checked for what a user sees.

One node process serves the feature tests. :data:`FEATURES` has one entry per feature:
the parameters that switch it on and the check of what a user then gets, compared with
the core on the same grasps (a new feature is one entry and its check). Then the node's
/diagnostics must report no internal error and all its workers, its output must hold no
error line, and Ctrl-C must end it cleanly. A node in each other environment a user may
have (a profiles file of their own, another middleware installed in the venv) must
publish markers too and end cleanly on SIGTERM. The in-process node tests (test/node/)
stay; this layer catches what only the real process does: its environment, its child
processes, DDS settings, signals (issue 28: markers never worked from grasp-fc-node).
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import yaml
from visualization_msgs.msg import MarkerArray

from grasp_fc_ros.client import GraspClient
from grasp_fc_ros.core import (
    Status,
    check_force_closure,
    epsilon_quality,
    holds_under,
    probability_of_force_closure,
    robustness,
    verify_certificates,
)
from grasp_fc_ros.markers.build import marker_namespace
from grasp_fc_ros.markers.publisher import MARKER_QOS
from grasp_fc_ros.node.dds_profile import READER_PROFILE
from grasp_fc_ros.objects import make_object, sample_grasps
from grasp_fc_ros.packed import RobustnessQuery, Verdicts
from ros_fixtures import REPLY_TIMEOUT_S, DiagnosticsWatch
from shipped_run import PARAMS_FILE, ScriptRun, error_lines, other_middlewares, user_environment

# A cold start compiles kernels (the epsilon ones with compute_epsilon) in the node and
# its workers; with numba's cache filled it takes seconds.
pytestmark = pytest.mark.timeout(600)

NAMESPACE = "/shipped"
START_TIMEOUT_S = 300.0
# The friction coefficient of the shipped params file (the grasps carry none).
MU = yaml.safe_load(PARAMS_FILE.read_text())["force_closure"]["ros__parameters"][
    "friction_coefficient"]
# The exact test's margin depends on which grasps share a solver call, to solver accuracy.
MARGIN_ATOL = 1e-6
MARGIN_RTOL = 1e-4
# Epsilon bounds: the node and the core search the same grasps with the same settings,
# equal to rounding; the upper bound of a grasp that is not force closure is 0 to twice
# the core's ZERO_UPPER_TOL of the wrench scale (order 1 here).
EPSILON_RTOL = 1e-9
NOT_FC_UPPER_ATOL = 2e-6
# mu* is checked this far (relative) above and below: far outside its certification.
MU_STEP = 1e-3
GAMMA = 0.01  # m: the torsional friction of the soft-contact queries


@dataclass
class Served:
    """The shipped node with every feature on, a client of it, and its answers to one
    batch and one service call of the same grasps (positions, normals: (N, 4, 3))."""

    node: ScriptRun
    client: GraspClient
    markers: MarkerListener
    positions: np.ndarray
    normals: np.ndarray
    batch: Verdicts
    service: Verdicts
    answers: dict[str, Verdicts] = field(init=False)

    def __post_init__(self) -> None:
        self.answers = {"batch": self.batch, "service": self.service}


class MarkerListener:
    """The MarkerArrays a viewer (RViz) gets on one node's ``markers`` topic, with the
    time each arrived."""

    def __init__(self, topic: str):
        from rclpy.node import Node

        from ros_fixtures import SpinThread

        self._lock = threading.Condition()
        self.arrays: list[tuple[float, MarkerArray]] = []
        node = Node("shipped_marker_viewer")
        self.subscription = node.create_subscription(MarkerArray, topic, self._on_array,
                                                     MARKER_QOS)
        self._spinner = SpinThread(node)

    def _on_array(self, msg: MarkerArray) -> None:
        with self._lock:
            self.arrays.append((time.monotonic(), msg))
            self._lock.notify_all()

    def arrival_of(self, query_ids: list[int], timeout: float = REPLY_TIMEOUT_S) -> float:
        """When the markers of every one of ``query_ids`` had arrived (monotonic s)."""
        wanted = {marker_namespace(i) for i in query_ids}

        def arrived() -> float | None:
            seen: set[str] = set()
            for at, array in self.arrays:
                seen |= {marker.ns for marker in array.markers}
                if wanted <= seen:
                    return at
            return None

        with self._lock:
            ok = self._lock.wait_for(lambda: arrived() is not None, timeout)
            assert ok, f"no markers of queries {query_ids} within {timeout} s"
            at = arrived()
        assert at is not None
        return at

    def close(self) -> None:
        self._spinner.stop()


def start_node(log_path: Path, namespace: str, parameters: dict[str, bool],
               env: dict[str, str] | None = None) -> tuple[ScriptRun, GraspClient]:
    """grasp-fc-node with the shipped params file and ``parameters`` on top, and a
    connected client."""
    args = ["--ros-args", "--params-file", str(PARAMS_FILE), "-r", f"__ns:={namespace}"]
    for name, value in parameters.items():
        args += ["-p", f"{name}:={str(value).lower()}"]
    node = ScriptRun("grasp-fc-node", args, log_path, env)
    client = GraspClient(f"{namespace}/force_closure")
    if not client.wait_for_node(timeout=START_TIMEOUT_S):
        client.close()
        node.stop(signal.SIGKILL)
        pytest.fail(f"grasp-fc-node did not come up; output:\n{node.output()}")
    return node, client


def grasps() -> tuple[np.ndarray, np.ndarray]:
    """40 random 4-finger box grasps: four fingers so that the filter runs too, and
    every kind of verdict occurs."""
    return sample_grasps(make_object("box"), 40, 4, np.random.default_rng(28))


def markers_after_answer(client: GraspClient, markers: MarkerListener,
                         positions: np.ndarray, normals: np.ndarray, first_id: int) -> float:
    """Seconds from a service call's answer to the arrival of its grasps' markers."""
    ids = list(range(first_id, first_id + len(positions)))
    client.call(positions, normals, ids=ids)
    answered = time.monotonic()
    return markers.arrival_of(ids) - answered


# --- the features: what a user switches on, and what they then see ---------------------

def check_markers(served: Served) -> None:
    """A service request's grasps get markers (issue 28: none ever came)."""
    markers_after_answer(served.client, served.markers, served.positions[:3],
                         served.normals[:3], first_id=9000)


def check_epsilon(served: Served) -> None:
    core = epsilon_quality(served.positions, served.normals, MU)
    for where, got in served.answers.items():
        assert got.epsilon_lower is not None and got.epsilon_upper is not None, where
        force_closure = got.status == Status.FORCE_CLOSURE
        assert (got.epsilon_lower <= got.epsilon_upper).all(), where
        np.testing.assert_array_equal(got.epsilon_lower > 0, force_closure, err_msg=where)
        np.testing.assert_allclose(got.epsilon_lower, core.lower, rtol=EPSILON_RTOL,
                                   err_msg=where)
        np.testing.assert_allclose(got.epsilon_upper[force_closure],
                                   core.upper[force_closure], rtol=EPSILON_RTOL, err_msg=where)
        np.testing.assert_allclose(got.epsilon_upper[~force_closure],
                                   core.upper[~force_closure], rtol=0, atol=NOT_FC_UPPER_ATOL,
                                   err_msg=where)


def check_certificates(served: Served) -> None:
    for where, got in served.answers.items():
        assert got.contact_forces is not None and got.separating_wrench is not None, where
        forces_ok, wrench_ok = verify_certificates(
            served.positions, served.normals, MU,
            got.contact_forces.reshape(served.positions.shape), got.separating_wrench)
        np.testing.assert_array_equal(forces_ok, got.status == Status.FORCE_CLOSURE,
                                      err_msg=where)
        np.testing.assert_array_equal(wrench_ok, got.status != Status.FORCE_CLOSURE,
                                      err_msg=where)


def check_min_friction(served: Served) -> None:
    """The core says force closure just above each mu*, not just below it."""
    for where, got in served.answers.items():
        assert got.min_friction is not None, where
        finite = np.isfinite(got.min_friction) & (got.min_friction > 0)
        assert finite.sum() >= len(finite) // 2, where
        mu_star = got.min_friction[finite][:, None]
        p, n = served.positions[finite], served.normals[finite]
        assert check_force_closure(p, n, mu_star * (1 + MU_STEP)).force_closure.all(), where
        assert not check_force_closure(p, n, mu_star * (1 - MU_STEP)).force_closure.any(), where


def check_soft_contacts(served: Served) -> None:
    """Queries with torsional friction: two opposite soft fingers hold (hard ones do
    not), as the core says, with certificates that verify as soft contacts."""
    direction = np.random.default_rng(3).normal(size=(10, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    positions = 0.03 * np.stack([direction, -direction], axis=1)
    normals = -positions
    got = served.client.check_batch(positions, normals, torsional_friction=GAMMA)
    core = check_force_closure(positions, normals, MU, torsional_friction=GAMMA)
    np.testing.assert_array_equal(got.status, core.status)
    assert (got.status == Status.FORCE_CLOSURE).all()
    assert not check_force_closure(positions, normals, MU).force_closure.any()
    assert got.contact_forces is not None and got.contact_torques is not None
    forces_ok, _ = verify_certificates(positions, normals, MU,
                                       got.contact_forces.reshape(positions.shape),
                                       torsional_friction=GAMMA,
                                       contact_torques=got.contact_torques.reshape(10, 2))
    assert forces_ok.all()


def check_robustness(served: Served) -> None:
    """assess_robustness (always served) gives the core's radii, holds answers and
    probabilities on the same grasps."""
    positions, normals = served.positions[:8], served.normals[:8]
    question = RobustnessQuery(position_error=0.002, normal_error=float(np.radians(3.0)),
                               friction_error=0.1, position_sigma=0.002,
                               normal_sigma=float(np.radians(3.0)), samples=200, seed=5)
    got = served.client.assess_robustness(positions, normals, MU, question,
                                          timeout=REPLY_TIMEOUT_S)
    assert got.robustness is not None
    rows, radii = got.robustness, robustness(positions, normals, MU)
    for name in ("normal_angle", "position_radius", "friction_drop"):
        np.testing.assert_array_equal(getattr(rows, name), getattr(radii, name), err_msg=name)
    held = holds_under(positions, normals, MU, position_error=question.position_error,
                       normal_error=question.normal_error,
                       friction_error=question.friction_error)
    np.testing.assert_array_equal(rows.holds, held.status)
    chance = probability_of_force_closure(
        positions, normals, MU, position_sigma=question.position_sigma,
        normal_sigma=question.normal_sigma, samples=question.samples, seed=question.seed,
        grasp_ids=np.arange(len(positions)))
    np.testing.assert_array_equal(rows.probability, chance.estimate)
    np.testing.assert_array_equal(rows.probability_lower, chance.lower)


@dataclass(frozen=True)
class Feature:
    """How a user switches a feature on (node parameters), and what they then see."""

    parameters: dict[str, bool]
    check: Callable[[Served], None]


FEATURES = {
    "markers": Feature({"publish_markers": True}, check_markers),
    "epsilon": Feature({"compute_epsilon": True}, check_epsilon),
    "certificates": Feature({"certificates": True}, check_certificates),
    "min_friction": Feature({"compute_min_friction": True}, check_min_friction),
    "soft_contacts": Feature({}, check_soft_contacts),
    "robustness": Feature({}, check_robustness),
}


@pytest.fixture(scope="module")
def served(ros, tmp_path_factory):
    positions, normals = grasps()
    parameters = {name: value for feature in FEATURES.values()
                  for name, value in feature.parameters.items()}
    node, client = start_node(tmp_path_factory.mktemp("shipped") / "grasp-fc-node.log",
                              NAMESPACE, parameters)
    markers = MarkerListener(f"{NAMESPACE}/markers")
    try:
        yield Served(node, client, markers, positions, normals,
                     batch=client.check_batch(positions, normals, timeout=START_TIMEOUT_S),
                     service=client.call(positions, normals, timeout=START_TIMEOUT_S))
    finally:
        markers.close()
        client.close()
        if node.process.poll() is None:
            node.stop(signal.SIGKILL)


def test_verdicts_are_the_cores(served):
    core = check_force_closure(served.positions, served.normals, MU)
    assert {Status.FORCE_CLOSURE, Status.NOT_FORCE_CLOSURE, Status.FILTERED_OUT} <= set(
        core.status.tolist()), "need every kind of verdict"
    for where, got in served.answers.items():
        np.testing.assert_array_equal(got.status, core.status, err_msg=where)
        np.testing.assert_array_equal(got.force_closure, core.force_closure, err_msg=where)
        np.testing.assert_allclose(got.margin, core.margin, rtol=MARGIN_RTOL, atol=MARGIN_ATOL,
                                   equal_nan=True, err_msg=where)
        assert not any(got.messages), where


@pytest.mark.parametrize("name", FEATURES)
def test_feature(served, name):
    FEATURES[name].check(served)


def test_diagnostics_report_no_internal_error_and_every_worker(served):
    from diagnostic_msgs.msg import DiagnosticStatus

    watch = DiagnosticsWatch(f"{NAMESPACE}/force_closure")
    try:
        # The node counts a marker array once its marker process answered, which may be
        # after the listener saw it (the process runs on CPU time nobody else wants).
        status = watch.wait_for(lambda level, values: values["markers_published"] != "0",
                                "markers published")
    finally:
        watch.close()
    values = {kv.key: kv.value for kv in status.values}
    assert status.level == DiagnosticStatus.OK, status.message
    assert values["callback_errors"] == "0" and values["solver_failures"] == "0", values
    assert values["workers_alive"] == values["workers_configured"] == "2", values
    assert int(values["markers_published"]) > 0, values


def test_ctrl_c_ends_the_node_cleanly_and_its_output_holds_no_error(served):
    assert served.node.stop(signal.SIGINT) == 0, served.node.output()
    output = served.node.output()
    assert error_lines(output) == [], output
    # The features were on: the -p overrides won over the params file.
    assert all(f"{name}=True" in output
               for name in ("certificates", "compute_min_friction", "compute_epsilon")), output


# --- other environments a user may have -------------------------------------------------

def environment_variants() -> dict[str, Callable[[Path], dict[str, str]]]:
    """Name: the extra environment (given a folder for files) of each variant."""
    def users_profiles_file(folder: Path) -> dict[str, str]:
        # A valid profiles file of the user's (the node's own profile as its text: what
        # matters is that the user set it, so the node leaves the profiles to it and its
        # marker process reads the same file).
        path = folder / "my_profiles.xml"
        path.write_text(READER_PROFILE)
        return {"FASTRTPS_DEFAULT_PROFILES_FILE": str(path)}

    variants = {"users_profiles_file": users_profiles_file}
    for rmw in other_middlewares():  # Fast DDS alone in this venv: none
        variants[rmw] = lambda _, rmw=rmw: {"RMW_IMPLEMENTATION": rmw}
    return variants


@pytest.mark.parametrize("variant", environment_variants())
def test_markers_arrive_in_other_environments_and_sigterm_ends_cleanly(ros, tmp_path, variant):
    env = user_environment(**environment_variants()[variant](tmp_path))
    namespace = f"/shipped_{variant}"
    node, client = start_node(tmp_path / "grasp-fc-node.log", namespace,
                              {"publish_markers": True}, env)
    markers = MarkerListener(f"{namespace}/markers")
    try:
        positions, normals = (a[:2] for a in grasps())
        markers_after_answer(client, markers, positions, normals, first_id=1)
    finally:
        markers.close()
        client.close()
        code = node.stop(signal.SIGTERM)
    output = node.output()
    assert code == 0, output
    assert error_lines(output) == [], output

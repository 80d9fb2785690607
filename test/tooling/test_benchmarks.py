"""Every benchmark's quick form runs and prints its figures, sane (no timing asserted:
speed targets belong to the benchmarks and docs/performance.md, not to tests).

Every ``benchmarks/bench_*.py`` is run with ``--quick`` (found by glob: a new script is
picked up without touching this file, and fails clearly if it has no ``--quick``). Each
run must exit 0 and print none of the words a benchmark prints when it lost or
miscounted something (:data:`FAILURE_WORDS`); :data:`EXPECTED` then lists, per script,
the lines its output must contain, as regular expressions. Convention: every group a
pattern captures is a figure, which must be a finite number > 0 (and below
``Line.below``); figures that must be 0 are written into the pattern as literal zeros.
:data:`OTHER_RUNS` checks a few options beyond the quick form. The scripts run two at a
time (:class:`Runner`), each with a wall-time limit; their figures are never compared
with a target, so sharing the machine changes nothing the test asserts.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from ros_domains import claim_domain_id

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"
SCRIPTS = sorted(path.stem for path in BENCHMARKS.glob("bench_*.py"))

#: Wall-time limit of one run (most quick forms take seconds to half a minute).
DEFAULT_TIMEOUT_S = 300.0

#: Printed only when a benchmark lost, miscounted or crashed.
# Whole words: a name such as FAST_LOSS_CONFIG in a heading is not a failure.
FAILURE_WORDS = re.compile(r"\b(Traceback|INCOMPLETE|LOST|LOSS|miscount|SOUNDNESS VIOLATION)\b")

#: A figure: digits with optional thousands separators and decimals, captured.
N = r"(\d[\d,]*(?:\.\d+)?)"


@dataclass(frozen=True)
class Line:
    """``count`` output lines match ``pattern`` (``re.search``); their captured figures
    are finite, > 0 and < ``below``."""

    pattern: str
    count: int = 1
    below: float = math.inf


@dataclass(frozen=True)
class Run:
    """What one run of a script must print; ``skip_if``: a pattern by which the script
    says it cannot measure here (the test is then skipped with that line)."""

    lines: tuple[Line, ...] = ()
    args: tuple[str, ...] = ("--quick",)
    timeout_s: float = DEFAULT_TIMEOUT_S
    skip_if: str | None = None


def _rows(first_columns: list[str], rest: str) -> tuple[Line, ...]:
    """One line per table row: its leading column(s), then ``rest``."""
    return tuple(Line(rf"^\s*{first}\s+{rest}$") for first in first_columns)


EXACT_CELLS = [rf"{n}\s+{mu}" for n in (4, 6, 8) for mu in (r"0\.176", r"0\.500")]
ROUND_TRIP = rf"p50\s+{N} ms\s+p99\s+{N} ms"

#: What the quick form of each script prints (scripts not listed get the generic checks).
EXPECTED: dict[str, Run] = {
    "bench_action": Run(lines=(
        Line(rf"^feedback: {N} messages over {N} s = {N} per s, largest gap {N} s"),
        # Either cancel may come after its goal ended on a loaded machine: then no latency.
        Line(r"^cancels: \d+ cut goals short, \d+ came after the goal ended; prefixes of "
             rf"{N}-{N} grasps, 0 lost, all equal the core$"),
        Line(rf"^throughput \(medians of 1 alternating rounds\): action {N} grasps/s, "
             rf"batch topic {N} grasps/s, ratio {N}$"),
    ), timeout_s=240),
    "bench_certificates": Run(lines=tuple(
        Line(rf"^\s+{tag}\s+batch\s+{N} grasps/s .*; single\s+{N} queries/s .*; "
             rf"verdict message\s+{N} B/grasp")
        for tag in ("off", "certificates", r"certificates\+min_friction"))),
    # --peer 3: the Qhull peer on three grasps as well (it costs ~20 ms a grasp).
    # Four client processes beside a busy one: each gets exactly its own answers.
    "bench_clients": Run(lines=(
        Line(r"client \d: 2000 answered, 0 lost, 0 wrong, batch answered whole", count=4),
        Line(r"lost answers: 0 \(target 0\); wrong answers: 0; batches answered whole: "
             r"4 of 4"),
        Line(r"single queries/s"),
    ), timeout_s=240),
    "bench_core": Run(args=("--quick", "--peer", "3"), lines=(
        Line(rf"^six fingers, 8-sided-pyramid Qhull peer {N} ms per grasp; filtered "
             rf"pipeline {N} ms \({N}x faster"),
        *_rows(["6", "3", "4", "8", "12"], rf"{N}\s+{N}\s+{N}\s+{N}\s+{N}\s+.*%"),
        Line(rf"^six fingers: filter {N} grasps/s"),
        # One grasp per call against the batch: no lone verdict or status differs.
        *_rows(["3", "4", "6", "8"], rf"{N}\s+{N}\s+{N}\s+500\s+1000\s+0\s+0"),
    )),
    "bench_epsilon": Run(lines=(
        # grasps, ours/s, peer/s; no violation, inconsistency or unconverged grasp.
        *_rows([r"4\s+0\.500", r"4\s+0\.176", r"6\s+0\.500", r"6\s+0\.176"],
               rf"24\s+[\d.]+\s+{N}\s+{N}\s+{N}\s+0\s+0\s+0\s+.*"),
        Line(r"^least ratio .*; violations 0, inconsistencies 0$"),
    )),
    "bench_first_call": Run(lines=(
        Line(rf"^first calls, fresh processes, installed cache: epsilon_quality {N} s, "
             rf"minimum_friction {N} s, optimal_contact_forces {N} s, check_force_closure "
             rf"{N} s$"),
    )),
    "bench_exact": Run(lines=(
        # clarabel and fast grasps/s, their ratio, +margin and its ratio; 0 disagreements.
        *_rows(EXACT_CELLS, rf"[\d.]+\s+{N}\s+{N}\s+{N}x\s+{N}\s+{N}x\s+\d+\s+0"),
        Line(rf"^one 6-finger grasp through check_force_closure \(.*\): {N} ms median of 200$",
             count=5),
    ), timeout_s=600),
    # A worker SIGKILLed mid-request, through the node and on the pool alone.
    "bench_faults": Run(lines=(
        Line(r"^node,.*worker \d+ SIGKILLed .*; 0 failures, 0 verdicts differ from the "
             r"core's"),
        Line(r"^engine,.*worker \d+ SIGKILLed .*; 0 failures, 0 verdicts differ from the "
             r"core's"),
        Line(r"no grasp lost to a worker's death: meets target"),
        # Workers killed while starting: all back, every kill counted (no time asserted).
        *(Line(rf"^{where}.*: (\d+) of \1 workers back {N} s after (\d+) kills .*; "
               r"worker_restarts \+\3 ") for where in ("node", "engine")),
    )),
    # A label job whose node is SIGKILLed mid-job and restarted: complete and equal.
    "bench_restart": Run(lines=(
        Line(rf"^killed {N} s into the job and restarted: the job ended {N} s after the "
             rf"restart, {N} goals sent again \({N} s after the restart\); (\d+) of \5 "
             r"verdicts, 0 differ from the core's"),
    )),
    # A KEEP_LAST publisher's burst at a stopped node: the rmw's loss report is its own
    # (a figure, not checked); every query received is answered, none counted twice.
    "bench_message_loss": Run(lines=(
        Line(rf"^round 1: {N} queries from a KEEP_LAST {N} publisher while the node was "
             r"stopped: [\d,]+ received \([\d,]+ overwritten\), [\d,]+ answered, [\d,]+ "
             r"reported lost by the rmw"),
        Line(r"^every received query answered, no more counted lost than overwritten: yes$"),
    )),
    # Service calls beside a 12-contact batch from another process and this one, and
    # beside a big service call; the batch (or call) answered in full every time.
    "bench_stall": Run(lines=(
        *(Line(rf"^{case} from {source}: p50 {N} ms, p99 {N} ms, max {N} ms over {N} calls")
          for case, source in (("batch", "another process"), ("goal", "another process"),
                               ("raw batch", "another process"),
                               ("raw goal", "another process"),
                               ("service call", "another process"),
                               ("batch", "this process"), ("goal", "this process"),
                               ("raw batch", "this process"))),
        # The quick form's raw batch (240,000 contacts) is within max_message_contacts.
        Line(r"the batch answered in [\d.]+ s, (\d+) of \1 grasps$", count=8),
    )),
    "bench_filter": Run(lines=(
        # n, mu, filter ms, exact ms, hit rate in [0, 1], saving, pays.
        Line(rf"^\s*\d+\s+[\d.]+\s+{N}\s+{N}\s+(?:0\.\d+|1\.0+)\s+-?[\d.]+\s+(?:yes|no)$",
             count=18),
        # At four contacts and mu = 0.01 the filter rejects most grasps.
        Line(r"^\s*4\s+0\.0100\s+[\d.]+\s+[\d.]+\s+(?:0\.[5-9]\d*|1\.0+)\s"),
        Line(r"^pays for every mu at n = "),
    )),
    "bench_label": Run(lines=(
        Line(rf"^core in-process, 1 core\s+:\s+{N} grasps/s"),
        Line(rf"1 worker\(s\) :\s+{N} grasps/s"),
        Line(rf"2 worker\(s\) :\s+{N} grasps/s"),
        Line(rf"^2 workers / 1 worker\s+:\s+{N}x"),
        Line(r"^large input: 60,000 three-finger grasps"),
        Line(rf"^large run .* worker peak RSS {N}, {N} MiB", below=4096),
    )),
    "bench_markers": Run(lines=(
        Line(rf"^core \(check_force_closure\)\s+{N} ms\s+1\.00 x core$"),
        Line(rf"^markers, 12 segments\s+{N} ms\s+{N} x core$"),
        Line(rf"^markers, 8 segments\s+{N} ms\s+{N} x core$"),
        Line(rf"^\s+topic\s+off: {ROUND_TRIP} \| on: {ROUND_TRIP} \| on/off p50\s+{N}"),
        Line(rf"^\s+service\s+off: {ROUND_TRIP} \| on: {ROUND_TRIP} \| on/off p50\s+{N}"),
        Line(r"^\s+marker arrays received by a listener process \d+ for 40 queries answered "
             r"with markers on; node: markers_published \d+, markers_dropped \d+$"),
        # Markers from grasp-fc-node started with them on (issue 28: none ever came).
        *(Line(rf"^\s+{setting}:\s+10 of 10 arrived; p50 {N} ms, max {N} ms")
          for setting in ("default environment", "a user's profiles file")),
    )),
    "bench_pool": Run(lines=(
        Line(rf"^core +{N} grasps/s; core in 2 processes +{N} \({N}x\); pool +{N} \({N}x\); "
             r"CPU per grasp: owner \d+\.\d+ us, workers \d+\.\d+ us$", count=2),
        Line(rf"^pool: median {N}x the core in one process$"),
    )),
    "bench_probability": Run(lines=(
        Line(rf"^\s+probability_of_force_closure\s+{N} samples/s \(mean estimate {N}, "
             r"undecided samples 0\)$"),
        Line(rf"^\s+exact test, random grasps\s+{N} grasps/s\s+-> ratio {N} \(target >= 0\.5\)$"),
        Line(rf"^\s+exact test, the same samples\s+{N} grasps/s\s+-> ratio {N}$"),
        Line(rf"^\s+\.\.\. without the filter\s+{N} grasps/s"),
        Line(rf"^\s+one grasp, 1,000 samples: median {N} ms, max {N} ms of {N} \(wall time\)$"),
    )),
    "bench_quality": Run(lines=(
        *_rows(["6", "4"], rf"256\s+{N}\s+{N}\s+{N}\s+{N}\s+.*"),
        Line(r"^n = 6: mu\* finite .*, unresolved 0;"),
        Line(r"^n = 4: mu\* finite .*, unresolved 0;"),
        Line(rf"^six fingers: mu\* {N} grasps/s"),
    )),
    "bench_robustness": Run(lines=(
        Line(rf"^speed n = [46], mu 0\.5: {N} grasps/s over {N} grasps \({N}% force closure\), "
             rf"{N} force-closure grasps/s$", count=2),
        Line(rf"^soundness: {N} perturbations \(tilts \(random\) {N}, moves \(random\) {N}, "),
        Line(r"^soundness: not force closure by the exact test \d+, of which certified by a "
             r"separating wrench 0$"),
        Line(rf"^tightness, normals: a searched tilt breaks within 1\.05x normal_angle on {N}% "),
        Line(rf"^tightness, positions: least breaking move / position_radius: median {N}, "
             rf"quartiles {N} {N}, max {N}, "),
        Line(r"^holds_under UNDECIDED \(all n\): normal 0\.5x [\d.]+%, normal 3x [\d.]+%, "
             r"position 0\.5x [\d.]+%, position 5x [\d.]+%, "),
        Line(rf"^holds_under witnesses: {N} BREAKS checked, 0 failed$"),
    )),
    "bench_ros": Run(lines=(
        Line(rf"^single-grasp topic:\s+{N} queries/s over 300 queries, no loss, in order"),
        Line(rf"^batches of 100: median of 3 rounds {N}x the core alone"),
        Line(rf"^service round trip \(one grasp\): p50 {N} ms, p99 {N} ms over 20 calls"),
        Line(r"^service round trip during a 20000-grasp batch: "),
        Line(rf"^service round trip, no core work \(invalid query\): p50 {N} ms, p99 {N} ms "
             r"over 20 calls$"),
    ), timeout_s=240),
    "bench_robustness_service": Run(lines=(
        Line(rf"^assess_robustness, one grasp x 1000 samples, idle: p50 {N} ms, p99 {N} ms "
             r"over 20 calls .*; answers differing from the core's: 0$"),
        Line(rf"^check_force_closure, one grasp, idle: p50 {N} ms, p99 {N} ms over 20 calls$"),
        Line(rf"^the work of one assessment \(engine, this process, CPU time\): p50 {N} ms, "
             rf"p99 {N} ms over 20 calls$"),
        *(Line(rf"^  of which {part} alone: p50 [\d.]+ ms, p99 {N} ms over 20 calls$")
          for part in ("probability", "robustness", "holds_under")),
        Line(rf"^check_force_closure, one grasp, during a 20-grasp x 1000-sample assessment "
             rf"\({N} s\): p50 {N} ms, p99 {N} ms over {N} calls$"),
    ), timeout_s=240),
    "bench_soak": Run(lines=(
        Line(r"^sent: .*; lost \(never answered\): 0 "),
        *(Line(rf"^\s+{kind}\s+latency p50\s+{N} ms, p99\s+{N} ms over {N}$")
          for kind in ("single", "batch", "service")),
        Line(rf"^node RSS: start {N} MiB, after warm-up {N} MiB, end {N} MiB, max {N} MiB "
             r"-> growth -?[\d.]+%"),
    )),
    "bench_soft": Run(lines=(
        Line(rf"^soundness: {N} random soft grasps .*, {N} filter rejections .*, "
             r"force-closure grasps rejected: 0$"),
        Line(r"^\s*4(?:\s+\d+\.\d+){9}$"),
    )),
}

#: Runs beyond the quick forms: options whose output the quick form does not show.
OTHER_RUNS: dict[str, tuple[str, Run]] = {
    # The node and the clients on two simulated hosts (network namespaces, UDP only).
    "bench_stall --udp-hosts": ("bench_stall", Run(
        args=("--quick", "--udp-hosts", "--cases", "batch,this"),
        lines=(*(Line(rf"^batch from {source}: p50 {N} ms, p99 {N} ms, max {N} ms over "
                      rf"{N} calls") for source in ("another process", "this process")),
               Line(r"the batch answered in [\d.]+ s, (\d+) of \1 grasps$", count=2),
               Line(r"^    UDP datagrams dropped at a full receive buffer: \d+ on the "
                    r"node's host, \d+ on the client's$", count=2)),
        skip_if=r"two hosts over UDP: skipped")),
    "bench_exact --against e89657b": ("bench_exact", Run(
        args=("--against", "e89657b", "--grasps", "60", "--repeats", "1"),
        lines=_rows(EXACT_CELLS, rf"[\d.]+\s+{N}\s+{N}\s+{N}x\s+{N}\s+{N}x\s+0"),
        skip_if=r"git history not available", timeout_s=600)),
    "bench_probability --coverage": ("bench_probability", Run(
        args=("--quick", "--coverage"),
        lines=(Line(rf"^\s+contains the reference: {N} of all grasps \(target >= 0\.94\); "
                    rf"{N} of the {N} with reference in \(0\.02, 0\.98\)$"),
               Line(r"undecided samples 0$")))),
    "bench_probability --blocks": ("bench_probability", Run(
        args=("--quick", "--blocks"),
        lines=(Line(rf"^\s+\d+\s+{N} samples/s, peak {N} MB \(tracemalloc\)$", count=3),))),
    "bench_exact --against unknown": ("bench_exact", Run(
        args=("--against", "0123456789abcdef", "--grasps", "60", "--repeats", "1"),
        lines=(Line(r"^--against 0123456789abcdef: git history not available"),
               Line(r"nothing measured")))),
}


#: Every run, by test id: the quick forms by script name, then :data:`OTHER_RUNS`.
ALL_RUNS: dict[str, tuple[str, Run]] = {
    **{script: (script, EXPECTED.get(script, Run())) for script in SCRIPTS}, **OTHER_RUNS}

#: Runs going at once. A run mostly waits (a node or a cluster starting, discovery,
#: the benchmarks' own pauses): two side by side take little longer than one.
IN_FLIGHT = 2


@dataclass
class _Started:
    process: subprocess.Popen
    deadline: float
    stdout: Path
    stderr: Path


class Runner:
    """Runs the selected tests' scripts in the order the tests come, the next one
    started while a test waits for its own; each in a process group of its own, killed
    whole (nodes and workers too) on timeout or when the module ends."""

    def __init__(self, order: list[str], environment: dict[str, str], folder: Path):
        self.order, self.environment, self.folder = order, environment, folder
        self.started: dict[str, _Started] = {}

    def _start(self, key: str) -> None:
        script, run = ALL_RUNS[key]
        name = re.sub(r"\W+", "_", key)
        stdout, stderr = self.folder / f"{name}.out", self.folder / f"{name}.err"
        with open(stdout, "wb") as out, open(stderr, "wb") as err:
            process = subprocess.Popen(
                [sys.executable, str(BENCHMARKS / f"{script}.py"), *run.args],
                stdout=out, stderr=err, env=self.environment, start_new_session=True)
        self.started[key] = _Started(process, time.monotonic() + run.timeout_s, stdout,
                                     stderr)

    def result(self, key: str) -> tuple[int, str, str]:
        """(exit status, standard output, standard error) of the run of test ``key``."""
        position = self.order.index(key) if key in self.order else len(self.order)
        for ahead in [key, *self.order[position + 1:position + IN_FLIGHT]]:
            if ahead not in self.started:
                self._start(ahead)
        started = self.started[key]
        try:
            status = started.process.wait(max(started.deadline - time.monotonic(), 0.0))
        except subprocess.TimeoutExpired:
            self._kill(started)
            pytest.fail(f"{key} did not finish within {ALL_RUNS[key][1].timeout_s:.0f} s:\n"
                        + started.stdout.read_text(errors="replace")
                        + started.stderr.read_text(errors="replace"))
        return (status, started.stdout.read_text(errors="replace"),
                started.stderr.read_text(errors="replace"))

    @staticmethod
    def _kill(started: _Started) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(started.process.pid, signal.SIGKILL)
        started.process.wait()

    def close(self) -> None:
        for started in self.started.values():
            if started.process.poll() is None:
                self._kill(started)


@pytest.fixture(scope="module")
def runner(request, tmp_path_factory) -> Iterator[Runner]:
    """The runner of this module's selected tests, on this run's own ROS_DOMAIN_ID (the
    node benchmarks start nodes), discovery on this machine only."""
    order = [item.callspec.id for item in request.session.items
             if item.module is request.module and hasattr(item, "callspec")]
    environment = {**os.environ, "ROS_DOMAIN_ID": str(claim_domain_id()),
                   "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    runner = Runner(order, environment, tmp_path_factory.mktemp("benchmarks"))
    yield runner
    runner.close()


def _output(runner: Runner, key: str) -> str:
    """The run's standard output; fails the test, with its output, if the run does."""
    script, run = ALL_RUNS[key]
    status, stdout, stderr = runner.result(key)
    if status == 2 and "unrecognized arguments: --quick" in stderr:
        pytest.fail(f"benchmarks/{script}.py has no --quick form: give it one (the smoke "
                    "test runs every benchmark with --quick; it should take well under a "
                    "minute)")
    output = stdout + stderr
    assert status == 0, f"{' '.join([script, *run.args])} exited {status}:\n{output}"
    failure = FAILURE_WORDS.search(output)
    assert failure is None, f"{script} printed {failure.group()!r}:\n{output}"
    return stdout


def _check(script: str, run: Run, output: str) -> None:
    lines = output.splitlines()
    if run.skip_if is not None:
        reason = next((line for line in lines if re.search(run.skip_if, line)), None)
        if reason is not None:
            pytest.skip(f"{script}: {reason}")
    assert any(re.search(N, line) for line in lines), f"{script} printed no figure:\n{output}"
    for expected in run.lines:
        found = [m for m in map(re.compile(expected.pattern).search, lines) if m]
        assert len(found) == expected.count, (
            f"{script}: {len(found)} lines match {expected.pattern!r}, expected "
            f"{expected.count}:\n{output}")
        for match in found:
            figures = [float(group.replace(",", "")) for group in match.groups()]
            assert all(0 < f < expected.below for f in figures), (
                f"{script}: figures {figures} of {match.group()!r} not in "
                f"(0, {expected.below}):\n{output}")


@pytest.mark.parametrize("script", SCRIPTS)
def test_quick_form_runs_and_prints_its_figures(script, runner):
    _check(script, ALL_RUNS[script][1], _output(runner, script))


@pytest.mark.parametrize("name", sorted(OTHER_RUNS))
def test_other_options(name, runner):
    script, run = OTHER_RUNS[name]
    _check(script, run, _output(runner, name))


def test_every_expectation_names_a_benchmark():
    """A script renamed or removed must take its expectations with it."""
    assert set(EXPECTED) <= set(SCRIPTS), sorted(set(EXPECTED) - set(SCRIPTS))
    assert {script for script, _ in OTHER_RUNS.values()} <= set(SCRIPTS)

"""Robustness radii and holds_under against the targets of issue 29, one core.

On random grasps of the built-in objects (grasp_fc_ros.objects: make_object,
sample_grasps), n = 3..8 contacts, one mu per grasp uniform in [0.2, 1.0]:

* soundness: perturbations inside 0.999x each radius (random ones, and searched ones:
  tilts towards -v_i of the wrench that separates the grasp shrunk just past the normal
  angle, the deepest moves for the torque directions nearest to breaking the grasp,
  every friction coefficient dropped at once) and mixed errors wherever holds_under says
  HOLDS (random perturbations inside all three errors, and the witness search's tilts
  and moves at those errors), each judged by the exact test; a "not force closure"
  verdict is checked again with certificates: one with a verified separating wrench is
  a loss of force closure (there must be none);
* tightness: the share of force-closure grasps where the searched tilt breaks force
  closure within 1.05x (and 1.002x, 1.01x) normal_angle, and the distribution of the
  least breaking move r* (the fine search of break_distance, each one confirmed by a
  witness the exact test certifies at 1.001 r*) over position_radius;
* holds_under: UNDECIDED shares at 0.5x and 3x the normal angle, 0.5x and 5x the
  position radius, 0.5x and 3x the friction drop, and mixed errors (each 0.3x and 0.5x
  its radius), per contact count; every BREAKS witness checked;
* speed: robustness on n = 4 and 6, mu 0.5, grasps per CPU second (median of
  ``--repeats``), over all grasps drawn and per force-closure grasp.

    python benchmarks/bench_robustness.py            # >= 10^6 perturbations (~minutes)
    python benchmarks/bench_robustness.py --quick    # the smoke test's form
"""

import os

# One core, as the targets are stated: keep BLAS and numba from spreading over both.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import importlib  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from functools import partial  # noqa: E402

import numpy as np  # noqa: E402

from grasp_fc_ros.core import (  # noqa: E402
    Holds,
    HoldsUnder,
    check_force_closure,
    exact_force_closure,
    holds_under,
    robustness,
    verify_certificates,
)
from grasp_fc_ros.core.model.grasp_input import GraspBatch, prepare_grasps  # noqa: E402
from grasp_fc_ros.objects import OBJECT_NAMES, make_object, sample_grasps  # noqa: E402

# The submodules by name: grasp_fc_ros.core.robustness is also the function's name.
break_distance = importlib.import_module("grasp_fc_ros.core.robustness.break_distance")
shrink = importlib.import_module("grasp_fc_ros.core.robustness.shrink")
witness = importlib.import_module("grasp_fc_ros.core.robustness.witness")
position_radius = importlib.import_module("grasp_fc_ros.core.robustness.position_radius")

FINGERS = tuple(range(3, 9))
MU_RANGE = (0.2, 1.0)
#: Inside each radius by this factor (the issue's 0.999x).
INSIDE = 0.999
#: Multiples of normal_angle at which the searched tilt is tried (the target: 1.05).
TILT_MULTIPLES = (1.002, 1.01, 1.05)
#: holds_under's error multiples (of each radius) whose UNDECIDED share is reported.
SINGLE_ERRORS = (("normal", 0.5), ("normal", 3.0), ("position", 0.5), ("position", 5.0),
                 ("friction", 0.5), ("friction", 3.0))
MIXED_SHARES = (0.3, 0.5)
#: A least breaking move r* counts as confirmed where the deepest moves of (1 + this) r*
#: for its torque direction break the grasp, certified by the exact test (at r* itself
#: the work vectors lie on the cones' boundaries, which no certificate can show).
CONFIRM_SLACK = 1e-3
#: Speed cells: contacts at mu 0.5.
SPEED_FINGERS = (4, 6)


@dataclass
class Grasps:
    """A set of grasps with their radii."""

    positions: np.ndarray
    normals: np.ndarray
    mu: np.ndarray                   # (N, n)
    angle: np.ndarray
    radius: np.ndarray
    drop: np.ndarray


def draw(n_fingers: int, per_object: int, seed: int) -> tuple[np.ndarray, np.ndarray,
                                                               np.ndarray]:
    """Grasps of every built-in object, one mu per grasp uniform in MU_RANGE."""
    rng = np.random.default_rng(seed + n_fingers)
    drawn = [sample_grasps(make_object(name), per_object, n_fingers, rng)
             for name in OBJECT_NAMES]
    positions = np.concatenate([p for p, _ in drawn])
    normals = np.concatenate([n for _, n in drawn])
    mu = np.repeat(rng.uniform(*MU_RANGE, (len(positions), 1)), n_fingers, axis=1)
    return positions, normals, mu


def closed_with_radii(positions: np.ndarray, normals: np.ndarray, mu: np.ndarray) -> Grasps:
    radii = robustness(positions, normals, mu)
    keep = radii.force_closure
    return Grasps(positions[keep], normals[keep], mu[keep], radii.normal_angle[keep],
                  radii.position_radius[keep], radii.friction_drop[keep])


class Judge:
    """The exact test on perturbed grasps; a "not force closure" is checked again with
    certificates (a verified separating wrench: a loss of force closure)."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}
        self.not_closed = 0
        self.certified = 0

    def __call__(self, kind: str, positions: np.ndarray, normals: np.ndarray,
                 mu: np.ndarray) -> None:
        self.counts[kind] = self.counts.get(kind, 0) + len(positions)
        for start in range(0, len(positions), 20_000):
            part = slice(start, start + 20_000)
            closed = exact_force_closure(positions[part], normals[part], mu[part])
            lost = np.flatnonzero(~closed)
            if lost.size:
                self.not_closed += lost.size
                again = check_force_closure(positions[part][lost], normals[part][lost],
                                            mu[part][lost], certificates=True)
                wrench = np.asarray(again.separating_wrench)
                self.certified += int(np.sum(~np.isnan(wrench).any(axis=1)))


def repeat(values: np.ndarray, times: int) -> np.ndarray:
    return np.repeat(values, times, axis=0)


def random_unit_across(rng: np.random.Generator, normals: np.ndarray) -> np.ndarray:
    across = np.cross(normals, rng.normal(size=normals.shape))
    return across / np.linalg.norm(across, axis=-1, keepdims=True)


def random_lengths(rng: np.random.Generator, shape: tuple[int, ...], power: float) -> np.ndarray:
    """Uniform in [0, 1] to the given power, every other one 1 (the boundary)."""
    lengths = rng.uniform(size=shape) ** power
    lengths[::2] = 1.0
    return lengths


def tilted(rng: np.random.Generator, normals: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Normals (K, n, 3) each turned by up to ``angle`` (K, 1) in a random azimuth."""
    turn = angle * random_lengths(rng, normals.shape[:2], 0.5)
    return (np.cos(turn)[..., None] * normals
            + np.sin(turn)[..., None] * random_unit_across(rng, normals))


def moved(rng: np.random.Generator, positions: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Positions (K, n, 3) each moved anywhere in the ball of ``radius`` (K, 1)."""
    direction = rng.normal(size=positions.shape)
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    length = radius * random_lengths(rng, positions.shape[:2], 1.0 / 3.0)
    return positions + length[..., None] * direction


def separating_past(grasps: Grasps, angle: np.ndarray) -> np.ndarray:
    """The separating wrenches (N, 6) of the grasps shrunk by ``angle`` (NaN: none, or a
    cone shrunk away)."""
    mu = shrink.tilted_friction(grasps.mu, angle[:, None])
    wrench = np.full((len(angle), 6), np.nan)
    keep = np.flatnonzero((mu > 0).all(axis=1))
    _, wrench[keep] = witness.exact_verdicts(GraspBatch(
        grasps.positions[keep], grasps.normals[keep], mu[keep], False, None))
    return wrench


def soundness(grasps: Grasps, per_grasp: int, rng: np.random.Generator, judge: Judge) -> None:
    """Single errors inside 0.999x their radii, random and searched."""
    k = max(per_grasp // 3, 2)
    p, n, mu = (repeat(x, k) for x in (grasps.positions, grasps.normals, grasps.mu))
    judge("tilts (random)", p, tilted(rng, n, repeat(INSIDE * grasps.angle[:, None], k)), mu)
    judge("moves (random)", moved(rng, p, repeat(INSIDE * grasps.radius[:, None], k)), n, mu)
    drops = repeat(INSIDE * grasps.drop[:, None], k) * random_lengths(rng, mu.shape, 1.0)
    judge("friction drops (random)", p, n, mu - drops)
    # Searched tilts: towards -v_i of the wrench just past the radius, and jittered.
    wrench = separating_past(grasps, grasps.angle * (1 + 2 * shrink.BRACKET_RTOL))
    has = ~np.isnan(wrench).any(axis=1)
    work = witness.work_vectors(grasps.positions[has], wrench[has])
    inside = INSIDE * grasps.angle[has, None] * np.ones(work.shape[:2])
    worst = witness.tilt_towards(grasps.normals[has], work, inside)
    judge("tilts (searched)", grasps.positions[has], worst, grasps.mu[has])
    jitter = max(k // 8, 1)
    base = repeat(worst, jitter)
    spread = repeat(grasps.angle[has, None], jitter) * 0.02 * rng.uniform(size=base.shape[:2])
    wobbled = witness.tilt_towards(repeat(grasps.normals[has], jitter), repeat(work, jitter),
                                   repeat(inside, jitter) - spread)
    wobbled = (np.cos(spread)[..., None] * wobbled
               + np.sin(spread)[..., None] * random_unit_across(rng, wobbled))
    judge("tilts (searched)", repeat(grasps.positions[has], jitter), wobbled,
          repeat(grasps.mu[has], jitter))
    # Searched moves: the deepest moves of 0.999 rho for the nearest torque directions.
    batch = prepare_grasps(grasps.positions, grasps.normals, grasps.mu)
    _, direction = break_distance.least_breaking_direction(batch)
    nearest = position_radius.torque_inradius(batch).direction
    for torque in (direction[:, 3:], nearest[:, 3:]):
        unit, centre, size = _normalised(grasps.positions)
        _, _, step = break_distance.deepest_moves(unit, grasps.normals, grasps.mu, torque,
                                                  INSIDE * grasps.radius / size)
        step *= size[:, None, None]
        length = np.linalg.norm(step, axis=-1, keepdims=True)
        step *= np.minimum(1.0, INSIDE * grasps.radius[:, None, None]
                           / np.maximum(length, 1e-300))
        judge("moves (searched)", grasps.positions + step, grasps.normals, grasps.mu)
    judge("friction drops (all at once)", grasps.positions, grasps.normals,
          grasps.mu - INSIDE * grasps.drop[:, None])


def _normalised(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    certificates = importlib.import_module("grasp_fc_ros.core.exact.certificates")
    return certificates.normalise_positions(positions)


def mixed_soundness(grasps: Grasps, per_grasp: int, rng: np.random.Generator,
                    judge: Judge) -> dict[float, np.ndarray]:
    """Where holds_under says HOLDS for each error at share x its radius: random
    perturbations inside all three errors, and the witness search's at them."""
    answers = {}
    for share in MIXED_SHARES:
        r, t, d = share * grasps.radius, share * grasps.angle, share * grasps.drop
        answer = holds_under(grasps.positions, grasps.normals, grasps.mu, position_error=r,
                             normal_error=t, friction_error=d)
        answers[share] = answer.status
        hold = answer.status == Holds.HOLDS
        k = max(per_grasp // (2 * len(MIXED_SHARES)), 2)
        p, n, mu = (repeat(x[hold], k) for x in (grasps.positions, grasps.normals, grasps.mu))
        judge("mixed (random)", moved(rng, p, repeat(INSIDE * r[hold, None], k)),
              tilted(rng, n, repeat(INSIDE * t[hold, None], k)),
              mu - repeat(INSIDE * d[hold, None], k) * random_lengths(rng, mu.shape, 1.0))
        # The witness search at the HOLDS errors: its moves and tilts must not break.
        held = GraspBatch(grasps.positions[hold], grasps.normals[hold],
                          shrink.tilted_friction(grasps.mu[hold] - INSIDE * d[hold, None],
                                                 INSIDE * t[hold, None]), False, None)
        if held.mu.size and (held.mu > 0).all():
            _, direction = break_distance.least_breaking_direction(held)
            unit, centre, size = _normalised(held.positions)
            _, force, step = break_distance.deepest_moves(
                unit, held.normals, held.mu, direction[:, 3:], INSIDE * r[hold] / size)
            step *= size[:, None, None]
            length = np.linalg.norm(step, axis=-1, keepdims=True)
            step *= np.minimum(1.0, INSIDE * r[hold, None, None] / np.maximum(length, 1e-300))
            wrench = np.concatenate([size[:, None] * force - np.cross(direction[:, 3:], centre),
                                     direction[:, 3:]], axis=1)
            positions = held.positions + step
            normals = witness.tilt_towards(
                held.normals, witness.work_vectors(positions, wrench),
                INSIDE * t[hold, None] * np.ones(held.mu.shape))
            judge("mixed (searched)", positions, normals,
                  grasps.mu[hold] - INSIDE * d[hold, None])
    return answers


def tightness(grasps: Grasps) -> tuple[dict[float, float], np.ndarray, int]:
    """Shares of grasps broken by the searched tilt (holds_under's witness) at each
    multiple of normal_angle, the verified break distances over rho, and how many were
    not confirmed by a witness."""
    broken_by = {}
    for multiple in TILT_MULTIPLES:
        answer = holds_under(grasps.positions, grasps.normals, grasps.mu,
                             normal_error=np.minimum(multiple * grasps.angle, np.pi))
        if assert_witnesses(answer):
            print("SOUNDNESS VIOLATION: a tilt witness does not check out")
        broken_by[multiple] = float(np.mean(answer.status == Holds.BREAKS))
    batch = prepare_grasps(grasps.positions, grasps.normals, grasps.mu)
    distance, direction = break_distance.least_breaking_direction(batch)
    found, _, _ = witness.moves_towards(batch, distance * (1 + CONFIRM_SLACK), direction[:, 3:])
    return broken_by, distance[found] / grasps.radius[found], int(np.sum(~found))


def undecided_shares(grasps: Grasps) -> tuple[dict[str, float], int, int]:
    """UNDECIDED share per single error, the BREAKS witnesses checked and failed."""
    shares, checked, failed = {}, 0, 0
    radius_of = {"normal": grasps.angle, "position": grasps.radius, "friction": grasps.drop}
    argument = {"normal": "normal_error", "position": "position_error",
                "friction": "friction_error"}
    for kind, multiple in SINGLE_ERRORS:
        error = multiple * radius_of[kind]
        if kind == "normal":
            error = np.minimum(error, np.pi)
        answer = holds_under(grasps.positions, grasps.normals, grasps.mu,
                             **{argument[kind]: error})
        shares[f"{kind} {multiple:g}x"] = float(np.mean(answer.status == Holds.UNDECIDED))
        checked += int(np.sum(answer.status == Holds.BREAKS))
        failed += assert_witnesses(answer)
    return shares, checked, failed


def assert_witnesses(answer: HoldsUnder) -> int:
    """How many BREAKS witnesses fail: the exact test says force closure, or their
    separating wrench does not check out."""
    breaks = answer.status == Holds.BREAKS
    if not breaks.any():
        return 0
    ok = verify_certificates(answer.witness_positions[breaks], answer.witness_normals[breaks],
                             answer.witness_mu[breaks],
                             separating_wrench=answer.separating_wrench[breaks])[1]
    closed = check_force_closure(answer.witness_positions[breaks],
                                 answer.witness_normals[breaks],
                                 answer.witness_mu[breaks]).force_closure
    return int(np.sum(~ok | closed))


def cpu_seconds(function: Callable[[], object]) -> float:
    start = time.process_time()
    function()
    return time.process_time() - start


def speed(per_object: int, repeats: int, seed: int) -> None:
    for n_fingers in SPEED_FINGERS:
        positions, normals, _ = draw(n_fingers, per_object, seed)
        robustness(positions[:3], normals[:3], 0.5)                  # compile or load
        closed = robustness(positions, normals, 0.5).force_closure
        seconds = statistics.median(cpu_seconds(partial(robustness, positions, normals, 0.5))
                                    for _ in range(repeats))
        print(f"speed n = {n_fingers}, mu 0.5: {len(positions) / seconds:,.0f} grasps/s over "
              f"{len(positions)} grasps ({100 * closed.mean():.0f}% force closure), "
              f"{closed.sum() / seconds:,.0f} force-closure grasps/s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="a few grasps (smoke test)")
    parser.add_argument("--per-object", type=int, default=None,
                        help="grasps per object and contact count (default 40; quick 3)")
    parser.add_argument("--perturbations", type=int, default=None,
                        help="soundness perturbations in all (default 10^6; quick 2e4)")
    parser.add_argument("--repeats", type=int, default=None, help="speed runs (median)")
    parser.add_argument("--seed", type=int, default=29)
    args = parser.parse_args()
    per_object = args.per_object or (3 if args.quick else 40)
    total = args.perturbations or (20_000 if args.quick else 1_000_000)
    repeats = args.repeats or (1 if args.quick else 3)
    fingers = (4, 6) if args.quick else FINGERS
    rng = np.random.default_rng(args.seed)

    speed(10 if args.quick else 100, repeats, args.seed)
    sets = {n: closed_with_radii(*draw(n, per_object, args.seed)) for n in fingers}
    n_closed = sum(len(g.angle) for g in sets.values())
    per_grasp = int(np.ceil(total / max(n_closed, 1) / 1.25))
    judge = Judge()
    mixed: dict[float, list[np.ndarray]] = {share: [] for share in MIXED_SHARES}
    print(f"grasps: {per_object} per object and n = {', '.join(map(str, fingers))}; "
          f"{n_closed} force closure, mu uniform in [{MU_RANGE[0]}, {MU_RANGE[1]}]")
    print(f"{'n':>2} {'FC':>5} {'normal':>9} {'position':>9} {'friction':>9}   (median radii)")
    for n_fingers, grasps in sets.items():
        print(f"{n_fingers:>2} {len(grasps.angle):>5} {np.median(grasps.angle):>9.4f} "
              f"{np.median(grasps.radius):>9.2e} {np.median(grasps.drop):>9.4f}")
        soundness(grasps, per_grasp, rng, judge)
        for share, status in mixed_soundness(grasps, per_grasp, rng, judge).items():
            mixed[share].append(status)
    kinds = ", ".join(f"{kind} {count:,}" for kind, count in judge.counts.items())
    print(f"soundness: {sum(judge.counts.values()):,} perturbations ({kinds})")
    print(f"soundness: not force closure by the exact test {judge.not_closed}, of which "
          f"certified by a separating wrench {judge.certified}"
          + (" SOUNDNESS VIOLATION" if judge.certified else ""))

    report_tightness(sets, n_closed)
    report_undecided(sets, mixed, n_closed)


def report_tightness(sets: dict[int, Grasps], n_closed: int) -> None:
    print(f"{'n':>2} " + " ".join(f"{m:>7g}x" for m in TILT_MULTIPLES)
          + "   (share of FC grasps a searched tilt breaks within the multiple)")
    ratios: list[np.ndarray] = []
    broken: dict[float, float] = dict.fromkeys(TILT_MULTIPLES, 0.0)
    unconfirmed = 0
    for n_fingers, grasps in sets.items():
        shares, ratio, missed = tightness(grasps)
        ratios.append(ratio)
        unconfirmed += missed
        for m in TILT_MULTIPLES:
            broken[m] += shares[m] * len(grasps.angle)
        print(f"{n_fingers:>2} " + " ".join(f"{100 * shares[m]:>7.1f}%" for m in TILT_MULTIPLES))
    overall = {m: broken[m] / max(n_closed, 1) for m in TILT_MULTIPLES}
    print(f"tightness, normals: a searched tilt breaks within 1.05x normal_angle on "
          f"{100 * overall[1.05]:.1f}% of force-closure grasps (1.002x: "
          f"{100 * overall[1.002]:.1f}%, 1.01x: {100 * overall[1.01]:.1f}%)")
    ratio = np.concatenate(ratios)
    q1, median, q3 = np.quantile(ratio, [0.25, 0.5, 0.75])
    print(f"tightness, positions: least breaking move / position_radius: median {median:.2f}, "
          f"quartiles {q1:.2f} {q3:.2f}, max {ratio.max():.1f}, over 2x "
          f"{100 * np.mean(ratio > 2):.0f}%, over 5x {100 * np.mean(ratio > 5):.1f}% "
          f"({len(ratio)} confirmed by a witness at {1 + CONFIRM_SLACK:g} r*, "
          f"{unconfirmed} not)")


def report_undecided(sets: dict[int, Grasps], mixed: dict[float, list[np.ndarray]],
                     n_closed: int) -> None:
    print(f"{'n':>2} " + " ".join(f"{kind[:4]} {m:g}x".rjust(10) for kind, m in SINGLE_ERRORS)
          + " " + " ".join(f"mixed {s:g}".rjust(10) for s in MIXED_SHARES)
          + "   (UNDECIDED share of FC grasps)")
    checked = failed = 0
    totals: dict[str, float] = {}
    for index, (n_fingers, grasps) in enumerate(sets.items()):
        shares, c, f = undecided_shares(grasps)
        checked, failed = checked + c, failed + f
        for share in MIXED_SHARES:
            shares[f"mixed {share:g}"] = float(np.mean(mixed[share][index] == Holds.UNDECIDED))
        for key, value in shares.items():
            totals[key] = totals.get(key, 0.0) + value * len(grasps.angle)
        print(f"{n_fingers:>2} " + " ".join(f"{100 * v:>9.1f}%" for v in shares.values()))
    print("holds_under UNDECIDED (all n): " + ", ".join(
        f"{key} {100 * value / max(n_closed, 1):.1f}%" for key, value in totals.items()))
    print(f"holds_under witnesses: {checked} BREAKS checked, {failed} failed"
          + (" SOUNDNESS VIOLATION" if failed else ""))


if __name__ == "__main__":
    main()

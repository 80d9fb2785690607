"""The probability of force closure under random contact errors: Monte Carlo sampling,
every sample decided by the exact test, with Clopper-Pearson bounds.

The error model
---------------
Each sample perturbs the nominal grasp (positions p_i, unit normals n_i, friction mu_i):

* positions: p_i' = p_i + e_i, e_i ~ N(0, position_sigma^2 I_3), independent per
  contact (isotropic, in the positions' unit);
* normals: n_i' = cos(theta_i) n_i + sin(theta_i) t_i, a tilt by the angle
  theta_i = |N(0, normal_sigma^2)| (radians: a half-normal) about a uniformly random
  axis perpendicular to n_i (t_i uniform on the unit circle of the tangent plane),
  independent per contact; the angle between n_i' and n_i is theta_i (at most theta_i
  where theta_i > pi wraps round, for huge sigmas);
* friction: mu_i' = mu_i + d, one offset d per sample shared by every contact (the
  friction guess of a hand-object pair is off as a whole, as in Dex-Net's sampling),
  d ~ N(0, friction_sigma^2) *truncated* to the offsets that keep every coefficient
  valid: min_i mu_i + d > 0 and max_i mu_i + d <= MAX_FRICTION_COEFFICIENT. It is drawn
  by the inverse distribution function (no resampling loop, no point mass at a floor).
  With one mu for all contacts and mu* the grasp's minimum friction coefficient,
  P(force closure) = P(d > mu* - mu) = (Phi(b) - Phi(max(a, (mu* - mu) / sigma)))
  / (Phi(b) - Phi(a)), a = -mu / sigma, b = (MAX - mu) / sigma.

Positions, normals and friction are independent. Torsional friction (soft fingers) is
kept as given: a soft finger's torsional limit mu' gamma follows its sampled mu'.

Sampling and reproducibility
----------------------------
Grasp k's samples come from its own stream, a PCG64 generator seeded by
``SeedSequence(seed, spawn_key=(grasp_ids[k],))`` (the k-th child ``spawn`` would give),
so a grasp's answer depends on ``seed``, its id and ``samples`` only: not on its batch
neighbours, the batch's order or size, nor on the block size. ``grasp_ids`` defaults to
0..N-1; a caller that splits a batch into parts (the labeller) passes each part's
global indices and gets the answers of the whole batch. Each sample's standard normals
are drawn as one row, so the first s samples of a call with ``samples`` > s are those
of the call with ``samples`` = s (a 25-sample label is a prefix of a 2,000-sample one).

Every sample is decided by the exact test (:func:`.pipeline.run_pipeline` without the
filter, verdicts only: the same verdicts), perturbed grasps of BLOCK_CONTACTS contacts
in all per call: memory stays bounded for any N x samples. A sample the solver cannot decide
(Status.SOLVER_FAILURE, rare) counts as neither: ``successes`` excludes it,
``undecided`` counts it, and the interval covers both readings (its lower end from
``successes``, its upper end from ``successes + undecided``).

The interval
------------
[lower, upper] is the two-sided Clopper-Pearson ("exact") interval at ``confidence``:
for k successes in S samples, lower = Beta^-1(alpha / 2; k, S - k + 1) (0 for k = 0)
and upper = Beta^-1(1 - alpha / 2; k + 1, S - k) (1 for k = S), alpha = 1 - confidence.
It covers the true probability with at least that probability, for every p and S.

Sample-free lower bound (normals only)
--------------------------------------
Where only the normals are noisy (``position_sigma`` = ``friction_sigma`` = 0) and the
contacts are hard, every choice of normals each within the grasp's certified
``normal_angle`` delta of its own keeps force closure (:func:`.radii.robustness`), and
each sampled normal is at most theta_i from its own, so P(force closure) >= P(every
theta_i <= delta) = prod_i P(|N(0, sigma^2)| <= delta) = erf(delta / (sigma sqrt 2))^n
(:func:`tilt_probability_bound`; the tilts are independent): ``normal_lower_bound``,
NaN under any other noise and for soft fingers (whose radii the core refuses).
"""

from __future__ import annotations

import secrets
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import special, stats

from ..exact.stacked_socp import tangent_bases
from ..model.grasp_input import GraspBatch, prepare_grasps
from ..pipeline import Status, run_pipeline
from ..tolerances import MAX_ABS_COORDINATE, MAX_FRICTION_COEFFICIENT
from .radii import robustness

#: Contacts of the perturbed grasps given to one call of the exact test (16,384 grasps
#: of 4 contacts, 1,024 of 64). Bounds the memory of a call whatever N x samples is:
#: its peak was 11.5 MB at 4, 8 and 32 contacts (tracemalloc); larger blocks gain little
#: (benchmarks/bench_probability.py --blocks, docs/performance.md#probability-of-force-closure).
BLOCK_CONTACTS = 65_536

#: Smallest sampled friction coefficient kept as drawn. The truncated offset d keeps
#: mu + d > 0 in exact arithmetic; rounding can still give 0 or a subnormal for an offset
#: within an ulp of the boundary (a chance of order 1e-16 per sample), which is lifted to
#: this, the smallest normal float, so that every sample is valid input (the largest
#: coefficient is kept at MAX_FRICTION_COEFFICIENT likewise).
MIN_SAMPLED_FRICTION = np.finfo(np.float64).tiny

_FORCE_CLOSURE, _SOLVER_FAILURE = int(Status.FORCE_CLOSURE), int(Status.SOLVER_FAILURE)


@dataclass(frozen=True)
class ForceClosureProbability:
    """Per grasp, the probability of force closure under the error model of the module
    docstring: (N,) arrays for a batch, their elements for one grasp.

    Attributes
    ----------
    estimate : ndarray of float
        successes / samples.
    lower, upper : ndarray of float
        The Clopper-Pearson interval at ``confidence`` (see the module docstring).
    successes : ndarray of int
        Samples the exact test certified force closure.
    samples : int
        Samples per grasp.
    confidence : float
        The interval's confidence level.
    normal_lower_bound : ndarray of float
        The sample-free lower bound where only the normals are noisy; NaN otherwise.
    undecided : ndarray of int
        Samples the solver could not decide (counted in ``upper`` only; almost always 0).
    """

    estimate: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    successes: np.ndarray
    samples: int
    confidence: float
    normal_lower_bound: np.ndarray
    undecided: np.ndarray


def probability_of_force_closure(
        positions: npt.ArrayLike, normals: npt.ArrayLike, mu: npt.ArrayLike, *,
        position_sigma: float = 0.0, normal_sigma: float = 0.0, friction_sigma: float = 0.0,
        samples: int = 1000, confidence: float = 0.95, seed: int | None = None,
        torsional_friction: npt.ArrayLike | None = 0.0,
        grasp_ids: npt.ArrayLike | None = None) -> ForceClosureProbability:
    """Estimate each grasp's probability of force closure under random contact errors.

    Parameters
    ----------
    positions : array_like, shape (n, 3) or (N, n, 3)
        Nominal contact positions (any length unit).
    normals : array_like, same shape as ``positions``
        Nominal inward normals, any non-zero length.
    mu : float or array_like broadcastable to (N, n)
        Nominal friction coefficients, > 0 (per grasp: (N, 1); per contact: (N, n)).
    position_sigma : float
        Standard deviation of each position coordinate's error (positions' unit), >= 0.
    normal_sigma : float
        Scale of each normal's tilt angle (radians), >= 0: the tilt is |N(0, sigma^2)|.
    friction_sigma : float
        Standard deviation of the friction offset shared by a sample's contacts, >= 0
        (truncated to keep every coefficient in (0, MAX_FRICTION_COEFFICIENT]).
    samples : int
        Samples per grasp, >= 1.
    confidence : float
        Confidence level of the interval, in (0, 1).
    seed : int or None
        Root seed (>= 0); None draws fresh entropy (not reproducible).
    torsional_friction : float or array_like broadcastable to (N, n)
        gamma of soft fingers (a length, kept as given); 0 (default): hard contacts.
    grasp_ids : array_like of int, shape (N,), optional
        Stream id of each grasp (>= 0); default 0..N-1. See the module docstring.

    Returns
    -------
    ForceClosureProbability

    Raises
    ------
    ValueError
        On bad grasps (naming grasp and contact) or a bad option (naming it).
    """
    sigmas = {name: _non_negative(value, name) for name, value in
              (("position_sigma", position_sigma), ("normal_sigma", normal_sigma),
               ("friction_sigma", friction_sigma))}
    samples = _positive_count(samples)
    confidence = _confidence(confidence)
    grasps = prepare_grasps(positions, normals, mu, torsional_friction)
    n_grasps = grasps.positions.shape[0]
    ids = _grasp_ids(grasp_ids, n_grasps)
    root = _seed(seed)
    # (fresh entropy as SeedSequence() draws it, kept to seed every grasp's stream)
    entropy = secrets.randbits(128) if root is None else root
    model = _ErrorModel(sigmas["position_sigma"], sigmas["normal_sigma"],
                        sigmas["friction_sigma"])
    successes = np.zeros(n_grasps, dtype=np.int64)
    undecided = np.zeros(n_grasps, dtype=np.int64)
    span, streams = (0, 0), []
    block = max(1, BLOCK_CONTACTS // grasps.positions.shape[1])
    for first, last, rows in _blocks(n_grasps, samples, block):
        if (first, last) != span:      # (a grasp drawn in parts keeps its generator)
            span, streams = (first, last), [_stream(entropy, int(ids[k]))
                                            for k in range(first, last)]
        _decide_block(grasps, first, last, rows, model, streams, successes, undecided)
    lower, upper = clopper_pearson(successes, successes + undecided, samples, confidence)
    bound = np.full(n_grasps, np.nan)
    if (model.position_sigma == model.friction_sigma == 0 and grasps.torsional is None
            and n_grasps):
        radii = robustness(grasps.positions, grasps.normals, grasps.mu)
        bound = tilt_probability_bound(radii.normal_angle, model.normal_sigma,
                                       grasps.positions.shape[1])
    return ForceClosureProbability(
        estimate=grasps.unbatch(successes / samples), lower=grasps.unbatch(lower),
        upper=grasps.unbatch(upper), successes=grasps.unbatch(successes), samples=samples,
        confidence=confidence, normal_lower_bound=grasps.unbatch(bound),
        undecided=grasps.unbatch(undecided))


def clopper_pearson(successes: npt.ArrayLike, successes_upper: npt.ArrayLike, samples: int,
                    confidence: float) -> tuple[np.ndarray, np.ndarray]:
    """The two-sided Clopper-Pearson interval of a binomial proportion.

    Parameters
    ----------
    successes : array_like of int, shape (N,)
        Successes for the lower end.
    successes_upper : array_like of int, shape (N,)
        Successes for the upper end (``successes`` plus any undecided trials).
    samples : int
        Trials per proportion.
    confidence : float
        Confidence level in (0, 1).

    Returns
    -------
    lower, upper : ndarray, shape (N,)
    """
    k = np.asarray(successes, dtype=np.float64)
    k_up = np.asarray(successes_upper, dtype=np.float64)
    tail = (1.0 - confidence) / 2.0
    with np.errstate(invalid="ignore", divide="ignore"):
        lower = np.where(k > 0, stats.beta.ppf(tail, k, samples - k + 1), 0.0)
        upper = np.where(k_up < samples, stats.beta.ppf(1.0 - tail, k_up + 1, samples - k_up),
                         1.0)
    return lower, upper


def tilt_probability_bound(normal_angle: npt.ArrayLike, normal_sigma: float,
                           n_contacts: int) -> np.ndarray:
    """P(every one of ``n_contacts`` tilts |N(0, sigma^2)| is <= ``normal_angle``).

    A lower bound on the probability of force closure where only the normals are noisy
    and ``normal_angle`` is a certified tilt radius (see the module docstring).

    Parameters
    ----------
    normal_angle : array_like, shape (N,)
        Certified tilt radii (radians, >= 0).
    normal_sigma : float
        Scale of the tilt angle (radians, >= 0).
    n_contacts : int
        Contacts per grasp.

    Returns
    -------
    ndarray, shape (N,)
        erf(delta / (sigma sqrt 2))^n; for sigma = 0, 1 where delta > 0 and 0 else.
    """
    delta = np.asarray(normal_angle, dtype=np.float64)
    if normal_sigma == 0.0:
        return np.where(delta > 0, 1.0, 0.0)
    return special.erf(delta / (normal_sigma * np.sqrt(2.0))) ** n_contacts


@dataclass(frozen=True)
class _ErrorModel:
    """The three error scales, and the columns of standard normals each sample draws."""

    position_sigma: float
    normal_sigma: float
    friction_sigma: float

    def columns(self, n_contacts: int) -> int:
        """Standard normals per sample: 3 per contact for its position error, 3 for its
        tilt (the angle, and a 2-D direction whose angle is uniform), 1 for friction;
        only for the errors whose sigma is > 0."""
        return (3 * n_contacts * (self.position_sigma > 0)
                + 3 * n_contacts * (self.normal_sigma > 0) + (self.friction_sigma > 0))

    def perturb(self, positions: np.ndarray, normals: np.ndarray, mu: np.ndarray,
                draws: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Perturbed grasps from nominal ones and standard normals.

        Parameters
        ----------
        positions, normals : ndarray, shape (G, n, 3)
            Nominal positions and unit normals of G grasps.
        mu : ndarray, shape (G, n)
        draws : ndarray, shape (G, S, columns(n))
            Standard normals, one row per sample.

        Returns
        -------
        positions, normals : ndarray, shape (G * S, n, 3)
        mu : ndarray, shape (G * S, n)
        """
        n_grasps, n_samples = draws.shape[:2]
        n_contacts = positions.shape[1]
        column = 0
        moved = np.broadcast_to(positions[:, None], (n_grasps, n_samples, n_contacts, 3))
        if self.position_sigma > 0:
            offsets = draws[..., :3 * n_contacts].reshape(n_grasps, n_samples, n_contacts, 3)
            moved = moved + self.position_sigma * offsets
            column = 3 * n_contacts
        tilted = np.broadcast_to(normals[:, None], moved.shape)
        if self.normal_sigma > 0:
            tilted = _tilt(normals, draws[..., column:column + 3 * n_contacts],
                           self.normal_sigma)
            column += 3 * n_contacts
        friction = np.broadcast_to(mu[:, None], moved.shape[:3])
        if self.friction_sigma > 0:
            friction = _shift_friction(mu, draws[..., column], self.friction_sigma)
        shape = (n_grasps * n_samples, n_contacts)
        return (np.reshape(moved, shape + (3,)), np.reshape(tilted, shape + (3,)),
                np.reshape(friction, shape))


def _tilt(normals: np.ndarray, draws: np.ndarray, sigma: float) -> np.ndarray:
    """Normals (G, n, 3) tilted per sample: (G, S, n, 3), from draws (G, S, 3 n).

    Columns 0..n-1 give the angles sigma |z|; columns n..3n-1, in pairs, a direction in
    each tangent plane (a 2-D standard normal has a uniform angle)."""
    n_contacts = normals.shape[1]
    angle = sigma * np.abs(draws[..., :n_contacts])
    pair = draws[..., n_contacts:].reshape(draws.shape[:2] + (n_contacts, 2))
    length = np.hypot(pair[..., 0], pair[..., 1])
    # (a pair of exact zeros has no direction: any axis will do, here the first tangent)
    safe = np.where(length > 0, length, 1.0)
    along_first = np.where(length > 0, pair[..., 0] / safe, 1.0)
    along_second = pair[..., 1] / safe
    first, second = tangent_bases(normals)
    sin_angle = np.sin(angle)
    return (np.cos(angle)[..., None] * normals[:, None]
            + (sin_angle * along_first)[..., None] * first[:, None]
            + (sin_angle * along_second)[..., None] * second[:, None])


def _shift_friction(mu: np.ndarray, draws: np.ndarray, sigma: float) -> np.ndarray:
    """Friction (G, n) shifted per sample by a truncated normal offset: (G, S, n).

    The offset d ~ N(0, sigma^2) restricted to -min_i mu_i < d <= MAX - max_i mu_i is
    sigma Phi^-1(Phi(a) + Phi(z) (Phi(b) - Phi(a))) for a standard normal z (the
    inverse distribution function of the truncated law at the uniform Phi(z))."""
    low = special.ndtr(-mu.min(axis=1) / sigma)[:, None]
    high = special.ndtr((MAX_FRICTION_COEFFICIENT - mu.max(axis=1)) / sigma)[:, None]
    offset = sigma * special.ndtri(low + special.ndtr(draws) * (high - low))
    shifted = mu[:, None, :] + offset[..., None]
    return np.clip(shifted, MIN_SAMPLED_FRICTION, MAX_FRICTION_COEFFICIENT)


def _blocks(n_grasps: int, samples: int, block: int) -> Any:
    """(first grasp, last grasp + 1, sample rows) per pipeline call: whole grasps,
    ``block // samples`` at a time, or for ``samples`` > ``block`` one grasp's samples
    in parts of at most ``block`` rows (in order, so its stream continues)."""
    if samples <= block:
        step = block // samples
        for first in range(0, n_grasps, step):
            yield first, min(first + step, n_grasps), samples
        return
    for grasp in range(n_grasps):
        for start in range(0, samples, block):
            yield grasp, grasp + 1, min(block, samples - start)


def _decide_block(grasps: GraspBatch, first: int, last: int, rows: int, model: _ErrorModel,
                  streams: list[np.random.Generator], successes: np.ndarray,
                  undecided: np.ndarray) -> None:
    """Draw ``rows`` samples of grasps first..last-1 from their ``streams``, decide them,
    add up the verdicts."""
    columns = model.columns(grasps.positions.shape[1])
    draws = np.empty((last - first, rows, columns))
    for k, stream in enumerate(streams):
        draws[k] = stream.standard_normal((rows, columns))
    positions, normals, mu = model.perturb(grasps.positions[first:last],
                                           grasps.normals[first:last],
                                           grasps.mu[first:last], draws)
    torsional = (None if grasps.torsional is None
                 else np.repeat(grasps.torsional[first:last], rows, axis=0))
    if model.position_sigma > 0 and not np.abs(positions).max() <= MAX_ABS_COORDINATE:
        raise ValueError(
            f"position_sigma = {model.position_sigma:g} moves contacts of grasps {first} to "
            f"{last - 1} beyond +-{MAX_ABS_COORDINATE:.3g}: use a larger length unit")
    sampled = GraspBatch(np.ascontiguousarray(positions), np.ascontiguousarray(normals),
                         np.ascontiguousarray(mu), single=False, torsional=torsional)
    # (the exact test alone: samples of one grasp are alike, so the filter rarely rejects
    # most of a block, and on perturbed grasps it costs more than it saves at n = 4,
    # docs/performance.md#probability-of-force-closure)
    status = run_pipeline(sampled, use_filter=False, margin="bound").status
    status = status.reshape(last - first, rows)
    successes[first:last] += (status == _FORCE_CLOSURE).sum(axis=1)
    undecided[first:last] += (status == _SOLVER_FAILURE).sum(axis=1)


def _stream(entropy: int, grasp_id: int) -> np.random.Generator:
    """Grasp ``grasp_id``'s generator under the root ``entropy``: the child
    ``SeedSequence(entropy).spawn`` would give it at that index."""
    return np.random.Generator(np.random.PCG64(
        np.random.SeedSequence(entropy, spawn_key=(grasp_id,))))


def _non_negative(value: Any, name: str) -> float:
    """A sigma: a real, finite number >= 0, else ValueError naming it."""
    if not (_is_number(value) and np.isfinite(value) and value >= 0):
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    return float(value)


def _positive_count(value: Any) -> int:
    if not (_is_integer(value) and value >= 1):
        raise ValueError(f"samples must be an integer >= 1, got {value!r}")
    return int(value)


def _confidence(value: Any) -> float:
    if not (_is_number(value) and 0.0 < value < 1.0):
        raise ValueError(f"confidence must be a number in (0, 1), got {value!r}")
    return float(value)


def _seed(value: Any) -> int | None:
    if value is not None and not (_is_integer(value) and value >= 0):
        raise ValueError(f"seed must be None or an integer >= 0, got {value!r}")
    return None if value is None else int(value)


def _is_number(value: Any) -> bool:
    """A real number, not a bool (a bool is an int to Python, but surely a mistake here)."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
        value, (bool, np.bool_))


def _is_integer(value: Any) -> bool:
    return _is_number(value) and isinstance(value, (int, np.integer))


def _grasp_ids(values: npt.ArrayLike | None, n_grasps: int) -> np.ndarray:
    """Stream ids (N,) of the grasps: 0..N-1 by default."""
    if values is None:
        return np.arange(n_grasps)
    ids = np.asarray(values)
    if ids.shape != (n_grasps,) or (ids.size and (
            not np.issubdtype(ids.dtype, np.integer) or ids.min() < 0)):
        raise ValueError(f"grasp_ids must be {n_grasps} integers >= 0 (one per grasp), got "
                         f"shape {ids.shape} of {ids.dtype}")
    return ids

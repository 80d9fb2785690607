"""The probability of force closure: the error model's distributions, interval coverage on
grasps of known probability, reproducibility and independence of batching, certain
grasps, soft fingers, bad input and empty batches."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import special, stats

from grasp_cases import ellipsoid_grasps
from grasp_fc_ros.core import check_force_closure, robustness
from grasp_fc_ros.core.robustness import (
    ForceClosureProbability,
    probability,
    probability_of_force_closure,
)
from grasp_fc_ros.core.robustness.probability import (
    _ErrorModel,
    _shift_friction,
    _tilt,
    clopper_pearson,
    tilt_probability_bound,
)
from grasp_fc_ros.core.tolerances import MAX_FRICTION_COEFFICIENT

OCTAHEDRON = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                      float)


def equator_grasp(tilt):
    """Three fingers at 120 degrees on the unit equator, normals tilted down by ``tilt``:
    mu* = tan(tilt) exactly (test_minimum_friction.equator_grasp)."""
    angle = 2 * np.pi * np.arange(3) / 3
    radial = np.stack([np.cos(angle), np.sin(angle), np.zeros(3)], axis=1)
    normals = -np.cos(tilt) * radial - np.sin(tilt) * np.array([0.0, 0.0, 1.0])
    return radial, normals


def friction_only_probability(mu, mu_star, sigma):
    """P(mu + d > mu*) for the truncated offset d of the module docstring."""
    low, high = -mu / sigma, (MAX_FRICTION_COEFFICIENT - mu) / sigma
    cut = max(low, (mu_star - mu) / sigma)
    return ((special.ndtr(high) - special.ndtr(cut))
            / (special.ndtr(high) - special.ndtr(low)))


# -- the error model -------------------------------------------------------------------


def test_tilts_have_the_half_normal_angle_and_a_uniform_azimuth():
    rng = np.random.default_rng(0)
    normals = rng.normal(size=(3, 4, 3))
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    sigma = 0.2
    draws = rng.standard_normal((3, 20_000, 12))
    tilted = _tilt(normals, draws, sigma)
    assert np.allclose(np.linalg.norm(tilted, axis=-1), 1.0, atol=1e-12)
    cosine = np.clip(np.einsum("gsnk,gnk->gsn", tilted, normals), -1, 1)
    assert np.allclose(np.arccos(cosine), sigma * np.abs(draws[..., :4]), atol=1e-7)
    # The angle's law: a half-normal of scale sigma (Kolmogorov-Smirnov).
    angles = np.arccos(cosine).ravel()
    assert stats.kstest(angles, stats.halfnorm(scale=sigma).cdf).pvalue > 1e-3
    # A uniform azimuth: the mean tangential direction vanishes.
    tangential = tilted - cosine[..., None] * normals[:, None]
    direction = tangential / np.linalg.norm(tangential, axis=-1, keepdims=True)
    assert np.abs(direction.mean(axis=1)).max() < 0.03


def test_friction_offsets_follow_the_truncated_normal_and_keep_mu_valid():
    rng = np.random.default_rng(1)
    mu = np.array([[0.05, 0.3, 0.2], [999.9, 999.0, 998.0]])
    sigma = 0.1
    shifted = _shift_friction(mu, rng.standard_normal((2, 50_000)), sigma)
    assert (shifted > 0).all() and (shifted <= MAX_FRICTION_COEFFICIENT).all()
    offsets = shifted - mu[:, None, :]
    # one offset per sample, shared by the contacts
    assert np.allclose(offsets, offsets[..., :1], atol=1e-12)
    for g in range(2):
        low = -mu[g].min() / sigma
        high = (MAX_FRICTION_COEFFICIENT - mu[g].max()) / sigma
        law = stats.truncnorm(low, high, scale=sigma)
        assert stats.kstest(offsets[g, :, 0], law.cdf).pvalue > 1e-3


def test_positions_get_isotropic_noise_of_the_given_sigma():
    rng = np.random.default_rng(2)
    positions = rng.normal(size=(2, 3, 3))
    normals = np.tile([0.0, 0.0, 1.0], (2, 3, 1))
    model = _ErrorModel(position_sigma=0.01, normal_sigma=0.0, friction_sigma=0.0)
    draws = rng.standard_normal((2, 40_000, model.columns(3)))
    moved, tilted, mu = model.perturb(positions, normals, np.full((2, 3), 0.5), draws)
    errors = (moved.reshape(2, 40_000, 3, 3) - positions[:, None]).reshape(-1, 3)
    assert np.allclose(np.cov(errors.T), 0.01 ** 2 * np.eye(3), atol=0.02 * 0.01 ** 2)
    assert (tilted == normals[0, 0]).all() and (mu == 0.5).all()


# -- known probabilities -----------------------------------------------------------------


def test_interval_covers_a_known_probability_at_its_confidence():
    """Friction noise only, on a grasp with mu* = tan(tilt) exactly: the probability is
    known in closed form. 400 independent 95% intervals (one stream per copy)."""
    mu_star, mu, sigma = 0.45, 0.5, 0.1
    positions, normals = equator_grasp(np.arctan(mu_star))
    copies = 400
    result = probability_of_force_closure(
        np.tile(positions, (copies, 1, 1)), np.tile(normals, (copies, 1, 1)), mu,
        friction_sigma=sigma, samples=200, seed=11)
    truth = friction_only_probability(mu, mu_star, sigma)
    inside = (result.lower <= truth) & (truth <= result.upper)
    assert inside.mean() >= 0.93            # Clopper-Pearson: >= 0.95 in law
    assert np.mean(result.estimate) == pytest.approx(truth, abs=0.01)   # 80,000 samples
    assert (result.undecided == 0).all()


@pytest.mark.parametrize("mu_star", [0.2, 0.7])
def test_friction_probability_matches_the_closed_form_on_both_sides(mu_star):
    positions, normals = equator_grasp(np.arctan(mu_star))
    result = probability_of_force_closure(positions, normals, 0.5, friction_sigma=0.15,
                                          samples=4000, seed=3)
    truth = friction_only_probability(0.5, mu_star, 0.15)
    assert result.lower <= truth <= result.upper


def test_deep_grasps_with_tiny_noise_are_certain_and_non_force_closure_never():
    deep = probability_of_force_closure(OCTAHEDRON, -OCTAHEDRON, 0.8, position_sigma=1e-4,
                                        normal_sigma=1e-4, friction_sigma=1e-4,
                                        samples=1000, seed=0)
    assert deep.successes == 1000 and deep.estimate == 1.0 and deep.upper == 1.0
    assert deep.lower == pytest.approx(0.025 ** (1 / 1000))
    # Every normal the same way: nothing pushes back.
    flat = probability_of_force_closure(OCTAHEDRON, np.tile([0.0, 0.0, 1.0], (6, 1)), 0.8,
                                        position_sigma=1e-4, normal_sigma=1e-4,
                                        friction_sigma=1e-4, samples=1000, seed=0)
    assert flat.successes == 0 and flat.lower == 0.0
    assert flat.upper == pytest.approx(1 - 0.025 ** (1 / 1000))


def test_without_noise_every_sample_is_the_nominal_verdict():
    rng = np.random.default_rng(4)
    positions, normals = ellipsoid_grasps(rng, 30, 4)
    nominal = check_force_closure(positions, normals, 0.5).force_closure
    result = probability_of_force_closure(positions, normals, 0.5, samples=20, seed=1)
    assert (result.estimate == nominal).all()


def test_soft_fingers_hold_where_hard_ones_cannot():
    """Two antipodal soft fingers are force closure; hard ones never are."""
    positions = np.array([[1.0, 0, 0], [-1.0, 0, 0]])
    noise = {"position_sigma": 1e-3, "normal_sigma": 1e-3, "friction_sigma": 1e-3}
    soft = probability_of_force_closure(positions, -positions, 0.5, torsional_friction=0.1,
                                        samples=200, seed=0, **noise)
    hard = probability_of_force_closure(positions, -positions, 0.5, samples=200, seed=0,
                                        **noise)
    assert soft.estimate == 1.0 and hard.estimate == 0.0


def test_per_contact_friction_is_used_per_contact():
    positions, normals = equator_grasp(np.arctan(0.45))
    same = probability_of_force_closure(positions, normals, np.full(3, 0.5),
                                        friction_sigma=0.1, samples=500, seed=2)
    scalar = probability_of_force_closure(positions, normals, 0.5, friction_sigma=0.1,
                                          samples=500, seed=2)
    assert same.successes == scalar.successes
    # One contact far below mu*: with the shared offset, never force closure.
    low = probability_of_force_closure(positions, normals, [0.5, 0.5, 0.05],
                                       friction_sigma=0.1, samples=500, seed=2)
    assert low.successes == 0


# -- the interval and the sample-free bound ----------------------------------------------


def test_clopper_pearson_edges_and_inversion():
    lower, upper = clopper_pearson([0, 10, 50], [0, 10, 50], 50, 0.95)
    assert lower[0] == 0 and upper[0] == pytest.approx(1 - 0.025 ** (1 / 50))
    assert upper[2] == 1 and lower[2] == pytest.approx(0.025 ** (1 / 50))
    # The ends are where the binomial tails equal alpha / 2.
    assert stats.binom.sf(9, 50, lower[1]) == pytest.approx(0.025)
    assert stats.binom.cdf(10, 50, upper[1]) == pytest.approx(0.025)
    # Undecided trials widen the upper end only.
    wide_lower, wide_upper = clopper_pearson([10], [14], 50, 0.95)
    assert wide_lower[0] == lower[1] and wide_upper[0] > upper[1]


def test_tilt_bound_is_the_probability_that_every_tilt_is_small():
    rng = np.random.default_rng(5)
    sigma, delta = 0.1, np.array([0.05, 0.15, 0.0])
    angles = sigma * np.abs(rng.standard_normal((200_000, 4)))
    empirical = [(angles <= d).all(axis=1).mean() for d in delta]
    assert tilt_probability_bound(delta, sigma, 4) == pytest.approx(empirical, abs=0.005)
    assert (tilt_probability_bound(delta, 0.0, 4) == [1.0, 1.0, 0.0]).all()


def test_the_sample_free_bound_holds_where_only_normals_are_noisy():
    """The bound from normal_angle is a lower bound on the probability: below every
    interval's upper end (2,000 samples), and tight where the tilts are tiny."""
    rng = np.random.default_rng(8)
    positions, normals = ellipsoid_grasps(rng, 60, 5)
    result = probability_of_force_closure(positions, normals, 0.6, normal_sigma=0.08,
                                          samples=2000, seed=4)
    radii = robustness(positions, normals, 0.6)
    expected = tilt_probability_bound(radii.normal_angle, 0.08, 5)
    np.testing.assert_array_equal(result.normal_lower_bound, expected)
    assert (result.normal_lower_bound <= result.upper).all()
    assert (result.normal_lower_bound[~radii.force_closure] == 0).all()
    assert (result.normal_lower_bound > 0.5).any()        # not vacuous
    tiny = probability_of_force_closure(OCTAHEDRON, -OCTAHEDRON, 0.8, normal_sigma=1e-3,
                                        samples=100, seed=0)
    assert tiny.normal_lower_bound == pytest.approx(1.0) and tiny.estimate == 1.0
    for noisy in ({"position_sigma": 1e-3}, {"friction_sigma": 1e-3}):
        other = probability_of_force_closure(positions[:3], normals[:3], 0.6,
                                             normal_sigma=0.08, samples=10, seed=4, **noisy)
        assert np.isnan(other.normal_lower_bound).all()
    soft = probability_of_force_closure(positions[:3], normals[:3], 0.6, normal_sigma=0.08,
                                        samples=10, seed=4, torsional_friction=0.01)
    assert np.isnan(soft.normal_lower_bound).all()


# -- reproducibility ---------------------------------------------------------------------

NOISE = {"position_sigma": 0.05, "normal_sigma": 0.1, "friction_sigma": 0.1}


def some_grasps(n_grasps=12, seed=6):
    return ellipsoid_grasps(np.random.default_rng(seed), n_grasps, 4)


def test_same_seed_same_answer_other_seed_other_answer():
    positions, normals = some_grasps()
    first = probability_of_force_closure(positions, normals, 0.5, samples=300, seed=9, **NOISE)
    again = probability_of_force_closure(positions, normals, 0.5, samples=300, seed=9, **NOISE)
    other = probability_of_force_closure(positions, normals, 0.5, samples=300, seed=10,
                                         **NOISE)
    assert (first.successes == again.successes).all()
    uncertain = (first.estimate > 0.05) & (first.estimate < 0.95)
    assert uncertain.any() and (first.successes != other.successes)[uncertain].any()


def test_a_grasps_answer_does_not_depend_on_its_batch(monkeypatch):
    """Reordered, split into parts (with their ids) or drawn in small blocks: the same."""
    positions, normals = some_grasps()
    whole = probability_of_force_closure(positions, normals, 0.5, samples=300, seed=9,
                                         **NOISE)
    order = np.random.default_rng(0).permutation(len(positions))
    shuffled = probability_of_force_closure(positions[order], normals[order], 0.5,
                                            samples=300, seed=9, grasp_ids=order, **NOISE)
    assert (shuffled.successes == whole.successes[order]).all()
    part = probability_of_force_closure(positions[5:8], normals[5:8], 0.5, samples=300,
                                        seed=9, grasp_ids=[5, 6, 7], **NOISE)
    assert (part.successes == whole.successes[5:8]).all()
    # Blocks smaller than a grasp's samples (its stream drawn in parts), and odd sizes.
    for block in (7, 128, 1000):                          # samples of 4 contacts
        monkeypatch.setattr(probability, "BLOCK_CONTACTS", 4 * block)
        blocked = probability_of_force_closure(positions, normals, 0.5, samples=300, seed=9,
                                               **NOISE)
        assert (blocked.successes == whole.successes).all()


def test_fewer_samples_are_a_prefix_of_more(monkeypatch):
    """The first 25 samples of a 300-sample call are those of a 25-sample call."""
    positions, normals = some_grasps(3)
    verdicts = []
    run_pipeline = probability.run_pipeline

    def recording(batch, **options):
        result = run_pipeline(batch, **options)
        verdicts.append(result.force_closure.reshape(3, -1))
        return result

    monkeypatch.setattr(probability, "run_pipeline", recording)
    probability_of_force_closure(positions, normals, 0.5, samples=300, seed=9, **NOISE)
    probability_of_force_closure(positions, normals, 0.5, samples=25, seed=9, **NOISE)
    assert (verdicts[0][:, :25] == verdicts[1]).all()
    assert (verdicts[0][:, :25] != verdicts[0][:, 25:50]).any()   # not one sample repeated


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), power=st.integers(-20, 20))
def test_scaling_grasp_and_position_noise_together_keeps_every_sample(seed, power):
    """A power-of-two scale is exact in floating point, and verdicts are scale invariant:
    the same seed gives the same successes."""
    positions, normals = ellipsoid_grasps(np.random.default_rng(seed), 3, 5)
    scale = 2.0 ** power
    noise = dict(NOISE, position_sigma=0.05)
    base = probability_of_force_closure(positions, normals, 0.5, samples=50, seed=seed,
                                        **noise)
    noise["position_sigma"] *= scale
    scaled = probability_of_force_closure(scale * positions, normals, 0.5, samples=50,
                                          seed=seed, **noise)
    assert (base.successes == scaled.successes).all()


# -- shapes, bad input -------------------------------------------------------------------


def test_one_grasp_gives_scalars_and_a_batch_arrays():
    positions, normals = some_grasps(2)
    one = probability_of_force_closure(positions[0], normals[0], 0.5, samples=10, seed=0,
                                       position_sigma=0.01)
    batch = probability_of_force_closure(positions, normals, 0.5, samples=10, seed=0,
                                         position_sigma=0.01)
    assert isinstance(one, ForceClosureProbability)
    assert np.ndim(one.estimate) == 0 and np.ndim(one.lower) == 0
    assert batch.estimate.shape == batch.upper.shape == batch.successes.shape == (2,)
    assert one.successes == batch.successes[0] and one.samples == 10
    assert np.isnan(batch.normal_lower_bound).all()   # noise beyond the normals: no bound


def test_an_empty_batch_gives_empty_results():
    result = probability_of_force_closure(np.zeros((0, 4, 3)), np.zeros((0, 4, 3)), 0.5,
                                          normal_sigma=0.1, samples=100, seed=0)
    for values in (result.estimate, result.lower, result.upper, result.successes,
                   result.normal_lower_bound, result.undecided):
        assert values.shape == (0,)


@pytest.mark.parametrize(("option", "value", "message"), [
    ("position_sigma", -1.0, "position_sigma must be a finite number >= 0"),
    ("normal_sigma", float("nan"), "normal_sigma must be a finite number >= 0"),
    ("friction_sigma", float("inf"), "friction_sigma must be a finite number >= 0"),
    ("friction_sigma", "0.1", "friction_sigma must be a finite number >= 0"),
    ("samples", 0, "samples must be an integer >= 1"),
    ("samples", 2.5, "samples must be an integer >= 1"),
    ("samples", True, "samples must be an integer >= 1"),
    ("confidence", 1.0, r"confidence must be a number in \(0, 1\)"),
    ("confidence", 0.0, r"confidence must be a number in \(0, 1\)"),
    ("seed", -1, "seed must be None or an integer >= 0"),
    ("seed", 1.5, "seed must be None or an integer >= 0"),
    ("grasp_ids", [0], "grasp_ids must be 2 integers >= 0"),
    ("grasp_ids", [0.0, 1.0], "grasp_ids must be 2 integers >= 0"),
    ("grasp_ids", [0, -1], "grasp_ids must be 2 integers >= 0"),
])
def test_bad_options_are_refused_by_name(option, value, message):
    positions, normals = some_grasps(2)
    with pytest.raises(ValueError, match=message):
        probability_of_force_closure(positions, normals, 0.5, **{option: value})


def test_noise_that_moves_contacts_out_of_range_is_refused():
    positions, normals = some_grasps(2)
    with pytest.raises(ValueError, match="position_sigma = 1e\\+305 moves contacts of grasps 0 "
                                         "to 1 beyond"):
        probability_of_force_closure(positions, normals, 0.5, position_sigma=1e305,
                                     samples=10, seed=0)


def test_bad_grasps_are_refused_naming_grasp_and_contact():
    positions, normals = some_grasps(3)
    normals[2, 1] = 0.0
    with pytest.raises(ValueError, match="grasp 2, contact 1: normal has zero length"):
        probability_of_force_closure(positions, normals, 0.5, normal_sigma=0.1)
    with pytest.raises(ValueError, match="friction coefficient must be > 0"):
        probability_of_force_closure(positions[:2], normals[:2], -0.5)

"""GM-PHD update (Stone Soup oracle), GCI fusion (closed form), agents ([GMPHD] §2)."""

import datetime

import numpy as np
import pytest

from baselines.acoustic.estimation.gci import GeneralizedCovarianceIntersection, LabelledExtractor
from baselines.acoustic.estimation.gmphd import (
    POSITION_H,
    AdaptiveBirth,
    ConstantVelocityModel,
    GaussianMixture,
    MixtureReducer,
    gmphd_update,
)
from baselines.kalman import joseph_covariance


def _random_spd(rng, n, scale):
    a = rng.normal(size=(n, n)) * scale
    return a @ a.T + scale**2 * np.eye(n)


def _case(seed=0, J=4, K=5):
    rng = np.random.default_rng(seed)
    w = rng.uniform(0.1, 1.0, J)
    m = rng.normal(size=(J, 6)) * [2, 2, 2, 0.5, 0.5, 0.5]
    P = np.stack([_random_spd(rng, 6, 0.7) for _ in range(J)])
    z = m[rng.integers(0, J, K), :3] + rng.normal(size=(K, 3))
    R = _random_spd(rng, 3, 0.5)
    return w, m, P, z, R


def test_single_band_update_equals_stone_soup():
    pytest.importorskip("stonesoup")
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.types.detection import Detection, MissedDetection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.multihypothesis import MultipleHypothesis
    from stonesoup.types.state import TaggedWeightedGaussianState
    from stonesoup.updater.kalman import KalmanUpdater
    from stonesoup.updater.pointprocess import PHDUpdater

    w, m, P, z, R = _case()
    pd, kappa = 0.8, 1e-3
    t = datetime.datetime(2024, 1, 1)
    model = LinearGaussian(ndim_state=6, mapping=(0, 1, 2), noise_covar=R)
    comps = [TaggedWeightedGaussianState(m[j][:, None], P[j], weight=w[j], tag=str(j),
                                         timestamp=t) for j in range(len(w))]
    dets = [Detection(zk[:, None], timestamp=t, measurement_model=model) for zk in z]
    hyps = [MultipleHypothesis([SingleHypothesis(c, d) for c in comps]) for d in dets]
    hyps.append(MultipleHypothesis([SingleHypothesis(c, MissedDetection(timestamp=t))
                                    for c in comps]))
    ref = PHDUpdater(KalmanUpdater(model), clutter_spatial_density=kappa, prob_detection=pd,
                     prob_survival=1.0).update(hyps)
    ref_w = np.array([float(c.weight) for c in ref])
    ref_m = np.array([np.asarray(c.mean, float).ravel() for c in ref])
    ref_P = np.array([np.asarray(c.covar, float) for c in ref])

    K, J = len(z), len(w)
    ow, om, oP, source = gmphd_update(w[None], m[None], P[None], z[None],
                                      np.broadcast_to(R, (1, K, 3, 3)), np.ones((1, K), bool),
                                      pd, kappa)
    # Stone Soup order: detection-major, then the missed terms.
    detected = (J + np.arange(J)[None, :] * K + np.arange(K)[:, None]).ravel()
    ours = np.concatenate([detected, np.arange(J)])
    np.testing.assert_allclose(ow[0, ours], ref_w, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(om[0, ours], ref_m, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(oP[0, ours], ref_P, rtol=1e-9, atol=1e-9)
    assert np.array_equal(source[ours[:J * K]], np.tile(np.arange(J), K))


def test_update_hand_computed_single_component():
    # One component, one detection, identity covariances: S = 2 I, K = [I/2; 0].
    m = np.zeros((1, 1, 6))
    P = np.eye(6)[None, None]
    z = np.array([[[1.0, 0.0, 0.0]]])
    R = np.eye(3)[None, None]
    ow, om, oP, _ = gmphd_update(np.ones((1, 1)), m, P, z, R, np.ones((1, 1), bool), 0.9, 0.1)
    q = (2 * np.pi * 2) ** -1.5 * np.exp(-0.25)
    assert ow[0, 0] == pytest.approx(0.1)
    assert ow[0, 1] == pytest.approx(0.9 * q / (0.1 + 0.9 * q), rel=1e-12)
    np.testing.assert_allclose(om[0, 1], [0.5, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(np.diag(oP[0, 1]), [0.5, 0.5, 0.5, 1, 1, 1])


def test_invalid_detections_are_ignored():
    w, m, P, z, R = _case(1)
    valid = np.array([[True, False, True, False, True]])
    R5 = np.broadcast_to(R, (1, 5, 3, 3))
    full = gmphd_update(w[None], m[None], P[None], z[None], R5, valid, 0.9, 1e-4)[0]
    J = len(w)
    dropped = full[0, J:].reshape(J, 5)[:, ~valid[0]]
    assert np.all(dropped == 0)
    # Whatever a padded fix holds (NaN here), it weighs 0 and leaves the real terms alone.
    z_nan = z.copy()
    z_nan[~valid[0]] = np.nan
    padded = gmphd_update(w[None], m[None], P[None], z_nan[None], R5, valid, 0.9, 1e-4)[0]
    assert np.all(padded[0, J:].reshape(J, 5)[:, ~valid[0]] == 0)
    np.testing.assert_array_equal(padded, full)


def _mix(m, P, w=1.0, label=0):
    return GaussianMixture(np.array([w]), np.asarray(m, float)[None],
                           np.asarray(P, float)[None], np.array([label]))


def test_gci_of_two_gaussians_is_covariance_intersection():
    rng = np.random.default_rng(4)
    P1, P2 = _random_spd(rng, 6, 0.5), _random_spd(rng, 6, 0.8)
    m1, m2 = rng.normal(size=6), rng.normal(size=6)
    om = 0.3
    fused = GeneralizedCovarianceIntersection([om, 1 - om])([_mix(m1, P1), _mix(m2, P2)])
    info = om * np.linalg.inv(P1) + (1 - om) * np.linalg.inv(P2)
    P = np.linalg.inv(info)
    mean = P @ (om * np.linalg.solve(P1, m1) + (1 - om) * np.linalg.solve(P2, m2))
    assert len(fused) == 1
    np.testing.assert_allclose(fused.covariances[0], P, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(fused.means[0], mean, rtol=1e-9, atol=1e-12)


def test_gci_weight_is_the_integral_of_the_geometric_mean():
    from scipy.integrate import quad
    from scipy.stats import norm

    # 1-D check of the powered-Gaussian constants: w = int N1^om N2^(1-om) dx.
    om, (m1, s1), (m2, s2) = 0.4, (0.0, 1.0), (1.5, 0.7)
    expected, _ = quad(lambda x: norm.pdf(x, m1, s1) ** om * norm.pdf(x, m2, s2) ** (1 - om),
                       -20, 20)
    a = GaussianMixture(np.array([1.0]), np.array([[m1]]), np.array([[[s1**2]]]),
                        np.array([0]))
    b = GaussianMixture(np.array([1.0]), np.array([[m2]]), np.array([[[s2**2]]]),
                        np.array([1]))
    fused = GeneralizedCovarianceIntersection([om, 1 - om])([a, b])
    assert fused.weights[0] == pytest.approx(expected, rel=1e-9)


def test_gci_with_unit_weight_returns_first_input():
    rng = np.random.default_rng(5)
    first = GaussianMixture(np.array([0.9, 0.2]), rng.normal(size=(2, 6)),
                            np.stack([_random_spd(rng, 6, 0.5) for _ in range(2)]),
                            np.array([3, 7]))
    second = _mix(rng.normal(size=6), _random_spd(rng, 6, 0.3))
    fused = GeneralizedCovarianceIntersection([1.0, 0.0])([first, second])
    for name in ("weights", "means", "covariances", "labels"):
        np.testing.assert_array_equal(getattr(fused, name), getattr(first, name))


def test_gci_bad_weights():
    with pytest.raises(ValueError, match="sum to 1"):
        GeneralizedCovarianceIntersection([0.5, 0.2])
    with pytest.raises(ValueError, match="expected 2 mixtures"):
        GeneralizedCovarianceIntersection([0.5, 0.5])([GaussianMixture.empty()])


def test_reducer_prunes_merges_and_caps():
    P = np.eye(6) * 0.01
    means = np.zeros((4, 6))
    means[1, 0] = 0.05  # within U of component 0
    means[2, 0] = 5.0
    means[3, 0] = 10.0
    mix = GaussianMixture(np.array([0.6, 0.3, 0.2, 1e-6]), means, np.stack([P] * 4),
                          np.array([1, 2, 3, 4]))
    out = MixtureReducer(1e-5, 4.0, max_components=5)(mix)
    assert len(out) == 2 and out.weights[0] == pytest.approx(0.9)
    assert out.means[0, 0] == pytest.approx(0.3 * 0.05 / 0.9)
    assert list(out.labels) == [1, 3]
    assert len(MixtureReducer(1e-5, 4.0, max_components=1)(mix)) == 1


def test_birth_clusters_weight_proportional_to_size():
    rng = np.random.default_rng(0)
    a = rng.normal([10, 10, -10], 0.1, (6, 3))
    b = rng.normal([50, 50, -10], 0.1, (3, 3))
    noise = np.array([[200.0, 200, -5]])
    w, m, P = AdaptiveBirth(eps=1.0, min_samples=3, weight=0.1, n_sources=10)(
        np.concatenate([a, b, noise]))
    order = np.argsort(-w)
    np.testing.assert_allclose(w[order], [0.06, 0.03])
    np.testing.assert_allclose(m[order][0, :3], a.mean(0))
    # Fixes explained by a confirmed component seed no birth.
    w2, _, _ = AdaptiveBirth(min_samples=3)(np.concatenate([a, b]), a[:1])
    assert len(w2) == 1


def test_constant_velocity_model():
    cv = ConstantVelocityModel(0.5, 2.0)
    m, P = cv.predict(np.array([1.0, 2, 3, 1, -1, 0]), np.zeros((6, 6)))
    np.testing.assert_allclose(m, [1.5, 1.5, 3, 1, -1, 0])
    np.testing.assert_allclose(P[0, 0], 4 * 0.5**4 / 4)
    np.testing.assert_allclose(P[0, 3], 4 * 0.5**3 / 2)


def test_extractor_keeps_labels():
    ext = LabelledExtractor(threshold=0.5, gate=1.0)
    mix = lambda x: GaussianMixture(np.array([0.9, 0.1]),  # noqa: E731
                                    np.array([[x, 0, 0, 0, 0, 0], [99, 0, 0, 0, 0, 0]]),
                                    np.stack([np.eye(6)] * 2), np.array([5, 6]))
    _, s1, l1 = ext(mix(0.0))
    _, s2, l2 = ext(mix(0.3))
    _, s3, l3 = ext(mix(5.0))
    assert len(s1) == 1 and l1[0] == l2[0] and l3[0] != l2[0]


def test_batched_reduction_equals_band_by_band():
    rng = np.random.default_rng(8)
    q, n = 4, 9
    w = rng.uniform(0, 1, (q, n)) * (rng.random((q, n)) < 0.8)
    w[2] = 0.0  # an empty band
    m = rng.normal(size=(q, n, 6)) * 0.3
    P = np.stack([[_random_spd(rng, 6, 0.3) for _ in range(n)] for _ in range(q)])
    labels = rng.integers(0, 100, (q, n))
    reducer = MixtureReducer(1e-5, 4.0, max_components=3)
    bw, bm, bP, bl = reducer.reduce(w, m, P, labels)
    for i in range(q):
        one = reducer(GaussianMixture(w[i], m[i], P[i], labels[i]))
        k = len(one)
        assert np.count_nonzero(bw[i]) == k
        np.testing.assert_allclose(bw[i, :k], one.weights, rtol=1e-12)
        np.testing.assert_allclose(bm[i, :k], one.means, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(bP[i, :k], one.covariances, rtol=1e-12, atol=1e-15)
        assert list(bl[i, :k]) == list(one.labels)
        assert np.all(bl[i, k:] == -1) and np.all(bw[i, k:] == 0)
    # The band-by-band reference, written out (Vo & Ma Table II) for band 0.
    keep = np.flatnonzero(w[0] > 1e-5)
    keep = keep[np.argsort(-w[0, keep], kind="stable")]
    j = keep[0]
    close = [i for i in keep
             if (m[0, i] - m[0, j]) @ np.linalg.solve(P[0, i], m[0, i] - m[0, j]) <= 4.0]
    assert bw[0, 0] == pytest.approx(w[0, close].sum(), rel=1e-12)


def test_gci_of_identical_inputs_returns_them():
    rng = np.random.default_rng(6)
    P = np.stack([_random_spd(rng, 6, 0.1) for _ in range(2)])
    means = np.zeros((2, 6))
    means[1, :3] = 50.0  # well separated: the mixture power is then (nearly) exact
    mix = GaussianMixture(np.array([0.8, 0.3]), means, P, np.array([4, 9]))
    fused = GeneralizedCovarianceIntersection([0.2] * 5)([mix] * 5)
    assert len(fused) >= 2
    np.testing.assert_allclose(fused.weights[:2], mix.weights, rtol=1e-9)
    np.testing.assert_allclose(fused.means[:2], mix.means, atol=1e-9)
    np.testing.assert_allclose(fused.covariances[:2], mix.covariances, rtol=1e-9, atol=1e-12)
    assert list(fused.labels[:2]) == [4, 9]
    assert np.all(fused.weights[2:] < 1e-12 * fused.weights[1])


def test_gci_of_three_gaussians_is_covariance_intersection():
    rng = np.random.default_rng(9)
    mixes = [_mix(rng.normal(size=6), _random_spd(rng, 6, 0.5 + 0.2 * i), w=0.5 + 0.1 * i)
             for i in range(3)]
    om = np.array([0.2, 0.3, 0.5])
    fused = GeneralizedCovarianceIntersection(om)(mixes)
    info = sum(o * np.linalg.inv(x.covariances[0]) for o, x in zip(om, mixes, strict=True))
    P = np.linalg.inv(info)
    mean = P @ sum(o * np.linalg.solve(x.covariances[0], x.means[0])
                   for o, x in zip(om, mixes, strict=True))
    np.testing.assert_allclose(fused.covariances[0], P, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(fused.means[0], mean, rtol=1e-9, atol=1e-12)
    # The weight is the integral of prod_q (w_q N_q)^om_q: check it by quadrature in 1-D.
    from scipy.integrate import quad
    from scipy.stats import norm

    params = list(zip((0.0, 1.0, -0.5), (1.0, 0.6, 1.4), (0.9, 0.4, 1.2), om, strict=True))
    one_d = [GaussianMixture(np.array([w]), np.array([[mu]]), np.array([[[s**2]]]),
                             np.array([i])) for i, (mu, s, w, _) in enumerate(params)]
    expected, _ = quad(lambda x: np.prod([(w * norm.pdf(x, mu, s)) ** o
                                          for mu, s, w, o in params]), -20, 20)
    got = GeneralizedCovarianceIntersection(om)(one_d).weights[0]
    assert got == pytest.approx(expected, rel=1e-9)


def test_joseph_covariance_equals_the_short_form_and_broadcasts():
    """With the optimal gain the Joseph form equals P - K H P (to round-off); batched
    calls equal one call per leading index."""
    rng = np.random.default_rng(12)
    P = np.stack([_random_spd(rng, 6, 0.6) for _ in range(3)])  # (3, 6, 6)
    R = np.stack([_random_spd(rng, 3, 0.4) for _ in range(2)])  # (2, 3, 3)
    S = P[:, None, :3, :3] + R[None]  # (3, 2, 3, 3)
    gain = np.swapaxes(P[:, None, :3, :], -1, -2) @ np.linalg.inv(S)  # (3, 2, 6, 3)
    batched = joseph_covariance(P[:, None], gain, POSITION_H, R[None])
    assert batched.shape == (3, 2, 6, 6)
    for i in range(3):
        for k in range(2):
            short = P[i] - gain[i, k] @ P[i, :3]
            np.testing.assert_allclose(batched[i, k], short, rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(joseph_covariance(P[i], gain[i, k], POSITION_H, R[k]),
                                       batched[i, k], rtol=1e-13, atol=1e-15)


def test_update_covariances_are_the_joseph_form():
    """gmphd_update regroups the Joseph form for H = [I_3, 0]; its covariances equal
    joseph_covariance with the same gain, also for centimetre fixes against a metre prior
    (the regime the Joseph form is there for), and stay symmetric positive definite."""
    for seed, r_scale in ((3, 0.5), (4, 0.01)):
        w, m, P, z, _ = _case(seed, J=3, K=4)
        rng = np.random.default_rng(seed)
        R = np.stack([_random_spd(rng, 3, r_scale) for _ in range(4)])  # (K, 3, 3)
        _, _, oP, _ = gmphd_update(w[None], m[None], P[None], z[None], R[None],
                                   np.ones((1, 4), bool), 0.9, 1e-3)
        S = P[:, None, :3, :3] + R[None]
        gain = np.swapaxes(P[:, None, :3, :], -1, -2) @ np.linalg.inv(S)  # (J, K, 6, 3)
        expected = joseph_covariance(P[:, None], gain, POSITION_H, R[None])
        updated = oP[0, len(w):].reshape(3, 4, 6, 6)
        scale = np.abs(expected).max()
        np.testing.assert_allclose(updated, expected, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(updated, np.swapaxes(updated, -1, -2), rtol=0,
                                   atol=1e-12 * scale)
        assert np.all(np.linalg.eigvalsh(updated) > 0)

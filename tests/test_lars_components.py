"""The LARS agents' components on their own: the AUV state estimators and the capture planner."""

import math

import gymnasium as gym
import numpy as np
import pytest

import auv_envs  # noqa: F401
from baselines.lars.control.arm import FOLLOW, STRIKE, TRACK, CaptureStrategy
from baselines.lars.control.capture import CapturePlanner
from baselines.lars.estimation.auv_state import (
    HeaveRefit,
    MarkerAUVEstimator,
    PitchYawMean,
    TrueStateAUVEstimator,
    prior_heave_model,
)
from baselines.lars.estimation.ckf import HeaveSurgeModel
from baselines.lars.perception.marker import MarkerLocaliser, attitude_rotation

DT = 0.04


@pytest.fixture(scope="module")
def scene():
    """The calibration, a joint configuration and an AUV pose in view of the cameras."""
    env = gym.make("auv_envs/LARSCapture-v0", obs_mode="features", pixel_noise_std=0.0)
    obs, info = env.reset(seed=0)
    env.close()
    return (env.unwrapped.calibration, obs["joint_position"].astype(float),
            info["true_position"].copy(), float(info["true_pitch"]), float(info["true_yaw"]))


def marker_pixels(cal, q, cg, rotation):
    """Noise-free (2, 3, 2) pixels of the marker corners of an AUV at ``cg`` seen at ``q``."""
    corners = cg + np.asarray(cal.marker.corners) @ rotation.T
    pose = cal.camera_poses(q)[0]  # world <- left camera
    in_left = (corners - pose[:3, 3]) @ pose[:3, :3]
    return cal.stereo.project(in_left)


def heave_track(t, cg0, amplitude=0.1, omega=2 * math.pi / 6.0, surge=0.02):
    """CG (3,) and velocity (3,) of a sinusoidal heave about ``cg0[2]`` with a slow surge."""
    pos = cg0 + np.array([surge * t, 0.0, amplitude * math.sin(omega * t)])
    vel = np.array([surge, 0.0, amplitude * omega * math.cos(omega * t)])
    return pos, vel


# ---------------------------------------------------------------- estimation components
def test_pitch_yaw_mean_is_plain_then_exponential():
    mean = PitchYawMean(memory=2)
    assert mean.rotation is None and math.isnan(mean.pitch)
    mean.update(0.1, 0.4)
    assert (mean.pitch, mean.yaw) == (0.1, 0.4)  # the first angle as it is
    mean.update(0.3, 0.0)
    assert mean.pitch == pytest.approx(0.2) and mean.yaw == pytest.approx(0.2)
    mean.update(0.4, 0.2)  # weight 1 / min(3, 2)
    assert mean.pitch == pytest.approx(0.3) and mean.yaw == pytest.approx(0.2)
    np.testing.assert_array_equal(mean.rotation, attitude_rotation(mean.pitch, mean.yaw))
    mean.reset()
    assert mean.rotation is None and mean.count == 0
    with pytest.raises(ValueError, match="memory"):
        PitchYawMean(0)


def test_heave_refit_recovers_frequency_and_level():
    prior = HeaveSurgeModel(DT, 2 * math.pi / 7.0, -0.05)
    refit = HeaveRefit(prior, window=15.0, min_span=3.0)
    omega, level = 2 * math.pi / 5.0, -0.12
    for k in range(70):  # 2.8 s: not enough yet
        t = k * DT
        refit.record(t, level + 0.1 * math.sin(omega * t + 0.3))
    assert not refit.refit(69 * DT) and refit.fit is None and refit.model is prior
    for k in range(70, 500):
        t = k * DT
        refit.record(t, level + 0.1 * math.sin(omega * t + 0.3))
    assert refit.refit(499 * DT)
    assert refit.fit.omega == pytest.approx(omega, rel=1e-4)
    assert refit.model.omega == refit.fit.omega and refit.model.z_mean == pytest.approx(level)
    assert refit.fit.span <= 15.0 + 1e-9  # only the last window is fitted
    refit.reset()
    assert refit.model is prior and refit.fit is None
    with pytest.raises(ValueError, match="min_span"):
        HeaveRefit(prior, window=1.0, min_span=2.0)


def make_estimator(cal, **kwargs):
    localiser = MarkerLocaliser(cal)
    heave = HeaveRefit(prior_heave_model(DT, cal.auv_freeboard - cal.auv_diameter / 2.0))
    return MarkerAUVEstimator(localiser, heave, PitchYawMean(), **kwargs)


def test_marker_estimator_tracks_a_synthetic_heave(scene):
    cal, q, cg0, pitch, yaw = scene
    rotation = attitude_rotation(pitch, yaw)
    est = make_estimator(cal)
    assert est.mean is None and not est.settled and est.rotation is None
    visible = np.ones((2, 3), bool)
    errors = []
    for k in range(250):  # 10 s
        t = k * DT
        pos, vel = heave_track(t, cg0)
        est.update(t, marker_pixels(cal, q, pos, rotation), visible, q)
        np.testing.assert_allclose(est.last_measurement, pos, atol=1e-9)  # noise-free fixes
        assert est.settled == (k + 1 >= round(0.5 / DT))  # 0.5 s of fixes
        errors.append(np.abs(est.mean - np.concatenate((pos, vel))))
    errors = np.array(errors)
    assert errors[50:, :3].max() < 2e-3 and errors[100:, 3:].max() < 0.02
    assert (est.pitch, est.yaw) == pytest.approx((pitch, yaw), abs=1e-9)
    assert est.fit is not None and est.fit.omega == pytest.approx(2 * math.pi / 6.0, rel=1e-3)
    assert est.filter.transition is est.model and est.model.omega == est.fit.omega
    # a fit every 0.5 s (12 updates) once the heights span 3 s
    fits = sum(1 for n in range(12, 251, 12) if (n - 1) * DT >= 3.0)
    assert est.counts["fixes"] == 250 and est.counts["heave_fits"] == fits
    assert est.counts["bridged"] == est.counts["gated"] == 0
    # the marker hidden: the filter bridges on eq. 8's model
    hidden = np.zeros((2, 3), bool)
    for k in range(250, 275):
        t = k * DT
        est.update(t, np.full((2, 3, 2), np.nan), hidden, q)
        assert est.last_measurement is None
    pos, _ = heave_track(274 * DT, cg0)
    assert est.counts["bridged"] == 25
    assert np.linalg.norm(est.mean[:3] - pos) < 0.01
    est.reset()
    assert est.mean is None and est.fit is None and est.counts["fixes"] == 0


def test_marker_estimator_gates_outliers_then_relocks(scene):
    cal, q, cg0, pitch, yaw = scene
    rotation = attitude_rotation(pitch, yaw)
    est = make_estimator(cal, relock_after=0.2)  # 5 gated fixes in a row: lost lock
    visible = np.ones((2, 3), bool)
    for k in range(40):
        est.update(k * DT, marker_pixels(cal, q, cg0, rotation), visible, q)
    assert est.settled
    moved = cg0 + (0.0, 0.0, 0.5)  # a jump no filter explains: gated, then relocked on
    for k in range(40, 46):
        est.update(k * DT, marker_pixels(cal, q, moved, rotation), visible, q)
    assert est.counts["gated"] == 5 and est.counts["reinitialised"] == 1
    assert not est.settled
    np.testing.assert_allclose(est.mean[:3], moved, atol=1e-9)


def test_true_state_estimator_takes_the_state_as_it_is():
    heave = HeaveRefit(HeaveSurgeModel(DT, 1.0, 0.0), min_span=1.0)
    est = TrueStateAUVEstimator(heave, refit_period=0.2)
    assert est.settled and est.mean is None
    for k in range(40):
        t = k * DT
        pos, vel = heave_track(t, np.zeros(3))
        est.update(t, pos, vel, 0.05, -0.2)
    np.testing.assert_array_equal(est.mean, np.concatenate((pos, vel)))
    assert (est.pitch, est.yaw) == (0.05, -0.2)
    fits = sum(1 for n in range(5, 41, 5) if (n - 1) * DT >= 1.0)  # every 0.2 s, 1 s on
    assert est.counts["heave_fits"] == fits and est.counts["fixes"] == 0


# ---------------------------------------------------------------- capture planner
class Estimate:
    """A hand-made estimate with the attributes the planner reads."""

    def __init__(self, model, mean, rotation, fit=None, settled=True):
        self.model, self.mean, self.rotation = model, np.asarray(mean, float), rotation
        self.fit, self.settled = fit, settled

    def kinematics(self, horizon):
        return self.model.kinematics(self.mean, horizon)


def make_planner(cal, **kwargs):
    return CapturePlanner(
        cal.arm, cal.joint_limits, MarkerLocaliser(cal),
        camera_in_end=0.5 * (cal.left_in_end[:3, 3] + cal.right_in_end[:3, 3]),
        tip_in_end=cal.capture_tip_in_end, auv_radius=cal.auv_diameter / 2.0, dt=DT,
        strategy=CaptureStrategy(hover_height=0.8, strike_duration=1.0, follow_timeout=0.4),
        sample_period=0.2, lookahead=0.4, **kwargs)


def test_planner_holds_until_the_estimate_settles(scene):
    cal, q, cg0, pitch, yaw = scene
    planner = make_planner(cal)
    model = HeaveSurgeModel(DT, 1.0, cg0[2])
    est = Estimate(model, np.concatenate((cg0, np.zeros(3))), attitude_rotation(pitch, yaw),
                   settled=False)
    zero = np.zeros(3)
    for k in range(3):
        q_ref, qd_ref, qdd_ref = planner.reference(k * DT, q + 0.01 * k, zero, est)
        np.testing.assert_array_equal(q_ref, q)  # the angles when the hold began
        assert not qd_ref.any() and not qdd_ref.any()
        assert planner.trajectory.segment is None
    est.settled = True
    q_ref, _, _ = planner.reference(3 * DT, q, zero, est)
    assert planner.trajectory.segment is not None and planner.phase == TRACK
    np.testing.assert_allclose(q_ref, q, atol=1e-6)  # the quintic starts where the arm is


def test_planner_phases_goals_and_replanning(scene):
    cal, q, cg0, pitch, yaw = scene
    rotation = attitude_rotation(pitch, yaw)
    model = HeaveSurgeModel(DT, 1.0, cg0[2])
    est = Estimate(model, np.concatenate((cg0, (0.0, 0.0, 0.05))), rotation)
    planner = make_planner(cal)
    localiser = MarkerLocaliser(cal)
    zero = np.zeros(3)
    # track: the end 0.8 m above the hull's top, the cameras' midpoint over the marker
    end, _, _ = planner.goal(TRACK, 0.4, est)
    pos, _, _ = model.kinematics(est.mean, 0.4)
    assert end[2] == pytest.approx(pos[2] + cal.auv_diameter / 2.0 + 0.8)
    slew = cal.arm.inverse_kinematics(end)[0]
    c, s = math.cos(slew), math.sin(slew)
    ox, oy = planner.camera_in_end[:2]
    np.testing.assert_allclose(end[:2] + (c * ox - s * oy, s * ox + c * oy),
                               localiser.marker_centre(pos, rotation)[:2], atol=1e-3)
    # strike/follow: the tip on the capture point
    tip, _, _ = planner.goal(STRIKE, 0.4, est)
    np.testing.assert_allclose(tip + cal.capture_tip_in_end,
                               localiser.capture_point(pos, rotation), atol=1e-12)
    segments, t = [], 0.0
    for k in range(10):  # rising, no heave fit: no strike
        t = k * DT
        planner.reference(t, q, zero, est)
        segments.append(planner.trajectory.segment)
    assert planner.phase == TRACK
    # a new quintic on the first call and every sample_period (5 steps)
    assert [i for i in range(1, 10) if segments[i] is not segments[i - 1]] == [4, 9]
    est.fit = object()  # heave fitted
    t += DT
    planner.reference(t, q, zero, est)
    assert planner.phase == TRACK  # still rising
    est.mean = np.concatenate((cg0, (0.0, 0.0, -0.01)))  # starts to sink: strike
    t += DT
    planner.reference(t, q, zero, est)
    assert planner.phase == STRIKE and planner.strategy.strikes == 1
    strike_end = planner.strategy.strike_end
    assert strike_end == pytest.approx(t + 1.0)
    assert planner.trajectory.segment.t1 == strike_end  # one quintic to contact
    while t < strike_end:
        t += DT
        planner.reference(t, q, zero, est)
    assert planner.phase == FOLLOW
    while t < strike_end + 0.4:
        t += DT
        planner.reference(t, q, zero, est)
    assert planner.phase == TRACK  # timed out: wait for the next crest
    assert planner.ik_failures == 0
    planner.reset()
    assert planner.phase == TRACK and planner.strategy.strikes == 0


def test_planner_without_strike_only_tracks(scene):
    cal, q, cg0, pitch, yaw = scene
    model = HeaveSurgeModel(DT, 1.0, cg0[2])
    planner = make_planner(cal, strike=False)
    est = Estimate(model, np.concatenate((cg0, (0.0, 0.0, 0.05))),
                   attitude_rotation(pitch, yaw), fit=object())
    for k, vz in enumerate((0.05, -0.05, 0.05, -0.05)):
        est.mean[5] = vz
        planner.reference(k * DT, q, np.zeros(3), est)
        assert planner.phase == TRACK


def test_planner_checks_its_periods(scene):
    cal = scene[0]
    with pytest.raises(ValueError, match="sample_period"):
        CapturePlanner(cal.arm, cal.joint_limits, MarkerLocaliser(cal), np.zeros(3),
                       np.zeros(3), 0.1, dt=DT, sample_period=0.01)

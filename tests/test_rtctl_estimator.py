"""EKF on slip and heading against a kinematic truth simulated here (issue 12).

The truth is the estimator's own motion model driven by the *true* wheel speeds, with slip,
crab and gyro bias doing the random walks the filter assumes, noisy encoders and gyro, and
sparse, delayed pose fixes. A consistent filter then has its Monte-Carlo-averaged normalised
estimation error squared (NEES) inside the 95 % chi-square band at ~95 % of the time steps
(Bar-Shalom, Li & Kirubarajan, "Estimation with Applications to Tracking and Navigation",
section 5.4.2). The closed-loop check against the full simulator is the simulator issue's.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import chi2

from rtctl.config import ControllerConfig, EstimatorSettings
from rtctl.estimator import STATE, EstimatorError, Odometry, SlipHeadingEKF, wheel_odometry, wrap_angle
from rtctl.messages import Pose

RS = 0.063  # shearing radius of the mini rover's wheel, m
DT = 0.2


def _simulate(seed: int, cfg: ControllerConfig, steps: int = 500, pose_every: int = 10, pose_delay: int = 2,
              slip0: float = 0.25, crab0: float = math.radians(4.0), bias0: float = 0.003,
              filter_cfg: ControllerConfig | None = None):
    """Run truth (noise of ``cfg``) and filter (tuned with ``filter_cfg``, default ``cfg``) together;
    return errors (steps, 6), covariances (steps, 6, 6), truth states and the filter."""
    rng = np.random.default_rng(seed)
    n = cfg.noise
    ekf = SlipHeadingEKF(filter_cfg or cfg, RS)
    ekf.reset(0.0)
    e = cfg.estimator
    # the truth starts inside the filter's initial uncertainty
    truth = np.array([rng.normal(0, e.initial_sigma_xy), rng.normal(0, e.initial_sigma_xy),
                      rng.normal(0, e.initial_sigma_heading),
                      slip0, crab0, bias0])
    errs, covs, truths = [], [], []
    pending: list[tuple[int, Pose]] = []
    for k in range(1, steps + 1):
        t = k * DT
        omega = 0.03 / (RS * 0.8) * (1 + 0.3 * math.sin(0.05 * t))  # commanded wheel speed
        steer = (0.05 * math.sin(0.1 * t), -0.02, 0.0, 0.1)
        r_true = 0.02 * math.sin(0.07 * t)  # a gentle S-curve
        v_odo_true, _ = wheel_odometry([omega] * 4, steer, [True] * 4, RS, n.wheel_speed)
        s = truth
        v = (1 - s[3]) * v_odo_true
        c = s[2] + s[4]
        s[0] += DT * v * math.cos(c) + rng.normal(0, n.position_walk * math.sqrt(DT))
        s[1] += DT * v * math.sin(c) + rng.normal(0, n.position_walk * math.sqrt(DT))
        s[2] = wrap_angle(s[2] + DT * r_true)
        s[3] += rng.normal(0, n.slip_walk * math.sqrt(DT))
        s[4] += rng.normal(0, n.crab_walk * math.sqrt(DT))
        s[5] += rng.normal(0, n.gyro_bias_walk * math.sqrt(DT))
        meas_w = [omega + rng.normal(0, n.wheel_speed) for _ in range(4)]
        meas_r = r_true + s[5] + rng.normal(0, n.gyro)
        v_odo, var = wheel_odometry(meas_w, steer, [True] * 4, RS, n.wheel_speed)
        # the gyro is integrated over the tick: its noise in the filter is per-sample, as here
        ekf.predict(t, Odometry(v_odo, var, meas_r))
        if k % pose_every == 0:
            pending.append((k + pose_delay, Pose(t, s[0] + rng.normal(0, n.pose_xy), s[1] + rng.normal(0, n.pose_xy),
                                                 float(wrap_angle(s[2] + rng.normal(0, n.pose_heading))))))
        for due, pose in [p for p in pending if p[0] == k]:
            verdict = ekf.update_pose(pose)
            assert verdict in ("accepted", "late", "gated", "reset"), verdict
        pending = [p for p in pending if p[0] > k]
        err = ekf.x - s
        err[2] = wrap_angle(err[2])
        errs.append(err)
        covs.append(ekf.P)
        truths.append(s.copy())
    return np.array(errs), np.array(covs), np.array(truths), ekf


def test_nees_inside_95_percent_band_over_seeds():
    """Monte-Carlo NEES of the full 6-state filter over 24 seeds and 500 steps (100 s each)."""
    cfg = ControllerConfig()
    runs = 24
    nees = []
    for seed in range(runs):
        errs, covs, _, ekf = _simulate(seed, cfg)
        nees.append(np.einsum("ki,kij,kj->k", errs, np.linalg.inv(covs), errs))
        assert ekf.counters.poses_late_used > 0
    avg = np.mean(nees, axis=0)  # (steps,)
    lo, hi = chi2.ppf([0.025, 0.975], df=6 * runs) / runs
    inside = np.mean((avg >= lo) & (avg <= hi))
    # a consistent filter: ~95 % inside; an overconfident or a pessimistic one falls far below
    assert inside >= 0.85, f"NEES inside [{lo:.2f}, {hi:.2f}] at only {inside:.0%} of steps (mean {avg.mean():.2f})"
    assert lo <= avg.mean() <= hi


def test_nees_check_detects_an_overconfident_filter():
    """The consistency test can fail: a filter told the encoders are 20x better than they are."""
    cfg = ControllerConfig()
    bad = replace(cfg, noise=replace(cfg.noise, wheel_speed=cfg.noise.wheel_speed / 20, slip_walk=cfg.noise.slip_walk / 20))
    runs = 8
    nees = []
    for seed in range(runs):
        # truth noise from the real config, filter from the bad one
        errs, covs, _, _ = _simulate(seed, cfg, filter_cfg=bad)
        nees.append(np.einsum("ki,kij,kj->k", errs, np.linalg.inv(covs), errs))
    avg = np.mean(nees, axis=0)
    hi = chi2.ppf(0.975, df=6 * runs) / runs
    assert np.mean(avg > hi) > 0.5


def test_slip_and_crab_estimated_within_a_few_points():
    """Slip within 3 points at every seed; crab within 2 deg on average over the seeds (its
    1-sigma is ~1.3 deg with a 1 deg pose heading every 2 s); gyro bias within 1 mrad/s."""
    cfg = ControllerConfig()
    crab = []
    for seed in range(4):
        errs, covs, truths, _ = _simulate(100 + seed, cfg, steps=600, slip0=0.3, crab0=math.radians(-5))
        tail = slice(-150, None)  # last 30 s
        assert np.abs(errs[tail, 3]).mean() < 0.03, f"seed {seed}: slip error {np.abs(errs[tail, 3]).mean():.3f}"
        crab.append(np.degrees(np.abs(errs[tail, 4]).mean()))
        assert np.abs(errs[tail, 5]).mean() < 1e-3  # gyro bias, rad/s
    assert np.mean(crab) < 2.0, crab


def test_heading_wraps_across_pi():
    """Driving through heading = pi: the filter's heading and its error stay wrapped and small."""
    cfg = ControllerConfig()
    ekf = SlipHeadingEKF(cfg, RS)
    ekf.reset(0.0, heading=math.pi - 0.02)
    for k in range(1, 30):
        ekf.predict(k * DT, Odometry(0.03, 1e-6, 0.01))
    h = ekf.x[2]
    assert -math.pi < h <= math.pi and h < 0  # crossed pi, wrapped to the negative side
    verdict = ekf.update_pose(Pose(29 * DT, ekf.x[0], ekf.x[1], h + 2 * math.pi))  # same angle, other branch
    assert verdict == "accepted" and ekf.last_mahalanobis < 1e-6


def _driven(ticks: int) -> SlipHeadingEKF:
    """A filter after ``ticks`` straight ticks at 3 cm/s odometry, no gyro rate."""
    ekf = SlipHeadingEKF(ControllerConfig(), RS)
    for k in range(1, ticks + 1):
        ekf.predict(k * DT, Odometry(0.03, 1e-6, 0.0))
    return ekf


def test_pose_handling_counters():
    ekf = _driven(20)
    x = ekf.x
    assert ekf.update_pose(Pose(ekf.t + 1.0, x[0], x[1], x[2])) == "future"
    assert ekf.update_pose(Pose(ekf.t - 10.0, x[0], x[1], x[2])) == "too_old"
    assert ekf.update_pose(Pose(ekf.t, math.nan, x[1], x[2])) == "invalid"
    assert ekf.update_pose(Pose(ekf.t, 3e6, x[1], x[2])) == "invalid"
    assert ekf.update_pose(Pose(ekf.t, x[0] + 5.0, x[1], x[2])) == "gated"
    c = ekf.counters
    assert (c.poses_future, c.poses_too_old, c.poses_gated, c.poses_accepted) == (1, 1, 1, 0)


def test_pose_on_a_clock_beyond_a_million_seconds():
    """A rover clock past 1e6 s (11.6 days) is a clock, not garbage: its fixes are used."""
    ekf = SlipHeadingEKF(ControllerConfig(), RS)
    ekf.reset(2e9)
    ekf.predict(2e9 + DT, Odometry(0.03, 1e-6, 0.0))
    x = ekf.x
    assert ekf.update_pose(Pose(2e9 + DT, x[0] + 0.005, x[1], x[2])) == "accepted"


def test_pose_jump_reinitialises_after_consistent_rejections():
    cfg = ControllerConfig()
    ekf = SlipHeadingEKF(cfg, RS)
    k = 0
    verdicts = []
    for i in range(cfg.estimator.reset_after_rejections + 1):
        for _ in range(5):
            k += 1
            ekf.predict(k * DT, Odometry(0.0, 1e-8, 0.0))
        x = ekf.x
        verdicts.append(ekf.update_pose(Pose(ekf.t, 1.0, -2.0, x[2])))  # the tracker jumped by >2 m
        if verdicts[-1] == "reset":
            break
    assert verdicts[:-1] == ["gated"] * (len(verdicts) - 1) and verdicts[-1] == "reset"
    assert ekf.counters.pose_resets == 1
    assert ekf.x[0] == pytest.approx(1.0) and ekf.x[1] == pytest.approx(-2.0)


def test_late_pose_equals_pose_on_time():
    """A fix applied late (after re-prediction) gives the state a filter that got it on time would
    have, to round-off: the rewind/re-predict path is the same arithmetic in another order."""
    cfg = ControllerConfig()
    inputs = [Odometry(0.03 + 0.001 * i, 1e-6, 0.01 * math.sin(i)) for i in range(1, 16)]
    pose = None
    a, b = SlipHeadingEKF(cfg, RS), SlipHeadingEKF(cfg, RS)
    for i, u in enumerate(inputs, start=1):
        a.predict(i * DT, u)
        b.predict(i * DT, u)
        if i == 10:
            x = a.x
            pose = Pose(i * DT, x[0] + 0.01, x[1] - 0.01, x[2] + 0.01)
            assert a.update_pose(pose) == "accepted"
    assert b.update_pose(pose) == "late"
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.P, b.P, rtol=0, atol=1e-14)


def test_late_pose_between_ticks_is_used_at_its_time():
    """A fix taken between two past ticks, 2 cm to the left of where the filter had the rover
    then: used late, it pulls the current estimate left (and not forward or back)."""
    ekf = _driven(10)
    t_fix = 5.5 * DT
    before = ekf.x
    v = (1 - before[3]) * 0.03
    assert ekf.update_pose(Pose(t_fix, v * t_fix, 0.02, 0.0)) == "late"
    after = ekf.x
    assert ekf.t == pytest.approx(10 * DT) and ekf.counters.poses_late_used == 1
    assert after[1] - before[1] > 0.005 and abs(after[0] - before[0]) < 0.01

def test_covariance_stays_symmetric_positive_definite():
    cfg = ControllerConfig()
    ekf = SlipHeadingEKF(cfg, RS)
    rng = np.random.default_rng(3)
    for k in range(1, 400):
        ekf.predict(k * DT, Odometry(float(rng.uniform(0, 0.1)), 1e-6, float(rng.normal(0, 0.1))))
        if k % 3 == 0:
            x = ekf.x
            ekf.update_pose(Pose(k * DT, x[0] + rng.normal(0, 0.01), x[1], x[2]))
        P = ekf.P
        assert np.array_equal(P, P.T)
        assert np.linalg.eigvalsh(P).min() > 0


def test_odometry_needs_usable_wheels_and_radius():
    v, var = wheel_odometry([1.0] * 4, [math.pi / 2] * 4, [True] * 4, RS, 0.02)
    assert math.isnan(v) and math.isinf(var)
    v, var = wheel_odometry([1.0, 1.0, 9.0, 1.0], [0.0] * 4, [True, True, False, True], RS, 0.02)
    assert v == pytest.approx(RS) and var == pytest.approx((0.02 * RS) ** 2 / 3)
    with pytest.raises(EstimatorError, match="wheel_radius"):
        SlipHeadingEKF(ControllerConfig(), 0.0)
    with pytest.raises(EstimatorError, match="time must increase"):
        SlipHeadingEKF(ControllerConfig(), RS).predict(0.0, Odometry(0.0, 1.0, 0.0))


def test_state_names():
    assert STATE == ("x", "y", "heading", "slip", "crab", "gyro_bias")
    assert isinstance(EstimatorSettings().reset_after_rejections, int)

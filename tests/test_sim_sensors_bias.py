"""Gyro bias random walk: the discrete increments have the density's variance, the truth
channel carries the bias the gyro really adds, runs stay deterministic per seed, and the walk
draws from its own generator (switching it off leaves every other noise sequence unchanged)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from offline.rover.primitives import solve_primitive
from offline.rover.scenario import example_scenarios, load_scenario
from offline.sim.sensors import GYRO_BIAS_WALK_ADIS16448, GyroBias, SensorConfig, SensorError
from offline.sim.simulator import RoverSimulator
from rtctl.messages import Commands

WHEELS = ("FR", "FL", "RR", "RL")


@pytest.mark.parametrize("dt", [0.05, 0.2])
def test_increments_have_the_density_variance(dt):
    cfg = SensorConfig(gyro_bias=0.001, gyro_bias_walk=GYRO_BIAS_WALK_ADIS16448)
    b = GyroBias(cfg, seed=11)
    path = np.array([cfg.gyro_bias] + [b.advance(dt) for _ in range(20000)])
    inc = np.diff(path)
    sigma = GYRO_BIAS_WALK_ADIS16448 * math.sqrt(dt)
    # sample std of 20000 normals: relative standard error 0.5 %
    assert np.std(inc) == pytest.approx(sigma, rel=0.03)
    assert abs(np.mean(inc)) < 4 * sigma / math.sqrt(len(inc))
    # independent increments (lag-1 autocorrelation within 4 standard errors of 0)
    assert abs(np.corrcoef(inc[:-1], inc[1:])[0, 1]) < 4 / math.sqrt(len(inc))


def test_zero_density_keeps_the_bias_and_negative_is_an_error():
    b = GyroBias(SensorConfig(gyro_bias=0.003, gyro_bias_walk=0.0), seed=1)
    assert all(b.advance(0.1) == 0.003 for _ in range(10))
    with pytest.raises(SensorError, match="gyro_bias_walk"):
        SensorConfig(gyro_bias_walk=-1e-5)
    with pytest.raises(SensorError, match="gyro_bias_walk"):
        SensorConfig(gyro_bias_walk=math.nan)


@pytest.fixture(scope="module")
def nominal():
    sc = load_scenario(next(p for p in example_scenarios() if p.stem == "nominal"))
    prim = solve_primitive(sc)
    return sc, Commands(0.0, 0, tuple(prim.wheels[k].rim_speed for k in WHEELS),
                        tuple(prim.wheels[k].steer for k in WHEELS))


def _run(sc, cmd, sensors, seed, ticks=10):
    sim = RoverSimulator(sc, sensors=sensors, seed=seed)
    sim.start(cmd)
    out = []
    for _ in range(ticks):
        m = sim.measure()
        out.append((m, sim.truth_state()))
        sim.apply(cmd)
        sim.advance(0.2)
    return out


def test_truth_carries_the_bias_the_gyro_adds_and_runs_are_deterministic(nominal):
    sc, cmd = nominal
    walk = 1e-3  # large, so the path is far from constant over 2 s
    quiet = SensorConfig(gyro_noise=0.0, gyro_bias=0.002, gyro_bias_walk=walk)
    a = _run(sc, cmd, quiet, seed=4)
    for m, ts in a:
        assert m.yaw_rate - ts.yaw_rate == pytest.approx(ts.gyro_bias, abs=1e-15)
    biases = [ts.gyro_bias for _, ts in a]
    assert biases[0] == 0.002 and len(set(biases)) == len(biases)
    assert [ts.gyro_bias for _, ts in _run(sc, cmd, quiet, seed=4)] == biases
    assert [ts.gyro_bias for _, ts in _run(sc, cmd, quiet, seed=5)] != biases
    # the walk has its own generator: every other measurement is unchanged without it
    b = _run(sc, cmd, SensorConfig(gyro_noise=0.0, gyro_bias=0.002, gyro_bias_walk=0.0), seed=4)
    for (ma, _), (mb, tb) in zip(a, b):
        assert ma.wheel_speed == mb.wheel_speed and ma.roll == mb.roll and ma.pose == mb.pose
        assert tb.gyro_bias == 0.002

"""Expected values for estim-core's UKF test (estim-core/tests/unscented.rs), computed by filterpy.

The problem is filterpy's own UKF radar test (filterpy/kalman/tests/test_ukf.py, `test_radar`
and its `RadarSim`): state [x, vx, alt], dt = 0.05 s, fx = constant velocity in x,
hx = sqrt(x^2 + alt^2), Q = 0.01 I, R = 10, x0 = [0, 90, 1100], P0 = 100 I, 401 steps
(t = 0 .. 20 s), measurements from RadarSim after numpy.random.seed(200) (the test's seed).

filterpy's test_radar uses JulierSigmaPoints(n=3, kappa=0); this script runs that and
MerweScaledSigmaPoints(n=3, alpha=0.1, beta=2, kappa=0) on the same measurements.

Writes estim-core/tests/data/filterpy_radar.csv, one row per (points, step):
points (julier | merwe), step, z (the measurement), x0..x2 and P00, P01, ..., P22
(row-major) after filterpy's predict + update, every float as Python's repr (shortest
string that round-trips the f64). The Rust test reads only this file.

Run (once, outside CI; filterpy is never a test dependency):
    pip install filterpy numpy
    python3 training/peers/filterpy_radar.py
"""

import os

import filterpy
import numpy as np
from filterpy.kalman import JulierSigmaPoints, MerweScaledSigmaPoints, UnscentedKalmanFilter

DT = 0.05
SEED = 200


class RadarSim:
    """filterpy's RadarSim (test_ukf.py), unchanged."""

    def __init__(self, dt):
        self.x = 0
        self.dt = dt

    def get_range(self):
        vel = 100 + 5 * np.random.randn()
        alt = 1000 + 10 * np.random.randn()
        self.x += vel * self.dt
        v = self.x * 0.05 * np.random.randn()
        return (self.x ** 2 + alt ** 2) ** .5 + v


def fx(x, dt):
    a = np.eye(3) + dt * np.array([[0, 1, 0], [0, 0, 0], [0, 0, 0]])
    return a.dot(x)


def hx(x):
    return [np.sqrt(x[0] ** 2 + x[2] ** 2)]


def measurements():
    np.random.seed(SEED)
    radar = RadarSim(DT)
    t = np.arange(0, 20 + DT, DT)
    return [radar.get_range() for _ in range(len(t))]


def run(points, zs):
    kf = UnscentedKalmanFilter(3, 1, DT, fx=fx, hx=hx, points=points)
    kf.Q *= 0.01
    kf.R = 10
    kf.x = np.array([0., 90., 1100.])
    kf.P *= 100.
    rows = []
    for z in zs:
        kf.predict()
        kf.update(z=[z])
        rows.append((np.array(kf.x, dtype=float), np.array(kf.P, dtype=float)))
    return rows


def main():
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    out = os.path.join(root, "estim-core", "tests", "data", "filterpy_radar.csv")
    zs = measurements()
    configs = [
        ("julier", JulierSigmaPoints(n=3, kappa=0.)),
        ("merwe", MerweScaledSigmaPoints(n=3, alpha=.1, beta=2., kappa=0.)),
    ]
    with open(out, "w") as f:
        f.write(f"# filterpy {filterpy.__version__}, numpy {np.__version__}: "
                "training/peers/filterpy_radar.py\n")
        f.write("points,step,z,x0,x1,x2," + ",".join(
            f"P{i}{j}" for i in range(3) for j in range(3)) + "\n")
        for name, points in configs:
            for step, (z, (x, p)) in enumerate(zip(zs, run(points, zs))):
                values = [float(z)] + list(x) + list(p.reshape(-1))
                f.write(f"{name},{step}," + ",".join(repr(float(v)) for v in values) + "\n")
    print(f"wrote {out}: {2 * len(zs)} rows")


if __name__ == "__main__":
    main()

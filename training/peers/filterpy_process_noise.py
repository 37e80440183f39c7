"""Expected values for estim-core's process-noise test (estim-core/tests/process_noise.rs),
computed by filterpy's own functions (filterpy.common.discretization):

- Q_discrete_white_noise(dim, dt, var, block_size, order_by_dim) and
  Q_continuous_white_noise(dim, dt, spectral_density, block_size, order_by_dim) for
  dim 2, 3, 4, dt 0.01 .. 2.5, two scales, block_size 1, and block_size 2 and 3 in both
  state orders;
- van_loan_discretization(F, G, dt) on four problems: Brown's example from filterpy's
  docstring (y'' + y = 2u, dt 0.1), constant velocity with G = [0, sqrt(0.7)]', a
  first-order Gauss-Markov (Singer) acceleration model, and a seeded random 4-state F
  with a 4 x 2 G (numpy.random.default_rng(7)).

Writes estim-core/tests/data/filterpy_process_noise.csv, one row per case:
kind (discrete | continuous | van_loan), case (index within its kind), dim, block_size,
order_by_dim (1 | 0), dt, scale (var or spectral_density; 1 for van_loan), then the
entries, row-major: for discrete / continuous the (dim block_size)^2 entries of Q; for
van_loan the dim^2 entries of F, then G G' (filterpy's noise density for its unit white
noise), then filterpy's Phi, then its Q. Every float as Python's repr (shortest string that
round-trips the f64). The Rust test reads only this file.

Run (once, outside CI; filterpy is never a test dependency):
    pip install --no-cache-dir filterpy numpy scipy
    python3 training/peers/filterpy_process_noise.py
"""

import os

import filterpy
import numpy as np
import scipy
from filterpy.common import Q_continuous_white_noise, Q_discrete_white_noise, van_loan_discretization


def flat(m):
    return [float(v) for v in np.asarray(m, dtype=float).reshape(-1)]


def chain_rows():
    rows = []
    for kind, fn in [("discrete", Q_discrete_white_noise), ("continuous", Q_continuous_white_noise)]:
        case = 0
        cases = [(dim, dt, scale, 1, True)
                 for dim in (2, 3, 4)
                 for dt in (0.01, 0.1, 1.0, 2.5)
                 for scale in (1.0, 0.37)]
        cases += [(dim, dt, scale, block, by_dim)
                  for dim in (2, 3, 4)
                  for (dt, scale) in ((0.1, 2.0), (1.3, 0.5))
                  for block in (2, 3)
                  for by_dim in (True, False)]
        for dim, dt, scale, block, by_dim in cases:
            q = fn(dim, dt, scale, block_size=block, order_by_dim=by_dim)
            rows.append([kind, case, dim, block, int(by_dim), dt, scale] + flat(q))
            case += 1
    return rows


def van_loan_problems():
    tau, sigma = 2.0, 0.3
    rng = np.random.default_rng(7)
    return [
        # Brown (2012) p. 126-7, filterpy's docstring example.
        (np.array([[0., 1.], [-1., 0.]]), np.array([[0.], [2.]]), 0.1),
        # Constant velocity, white acceleration of spectral density 0.7.
        (np.array([[0., 1.], [0., 0.]]), np.array([[0.], [np.sqrt(0.7)]]), 0.5),
        # Singer: position, velocity, Gauss-Markov acceleration (PSD 2 sigma^2 / tau).
        (np.array([[0., 1., 0.], [0., 0., 1.], [0., 0., -1. / tau]]),
         np.array([[0.], [0.], [np.sqrt(2. * sigma ** 2 / tau)]]), 0.2),
        # A general F (not normal, mixed stable and unstable modes) and G.
        (rng.uniform(-1., 1., (4, 4)), rng.uniform(-1., 1., (4, 2)), 0.3),
    ]


def van_loan_rows():
    rows = []
    for case, (f, g, dt) in enumerate(van_loan_problems()):
        phi, q = van_loan_discretization(f, g, dt)
        n = f.shape[0]
        rows.append(["van_loan", case, n, 1, 1, dt, 1.0]
                    + flat(f) + flat(g.dot(g.T)) + flat(phi) + flat(q))
    return rows


def main():
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    out = os.path.join(root, "estim-core", "tests", "data", "filterpy_process_noise.csv")
    rows = chain_rows() + van_loan_rows()
    with open(out, "w") as f:
        f.write(f"# filterpy {filterpy.__version__}, numpy {np.__version__}, scipy {scipy.__version__}: "
                "training/peers/filterpy_process_noise.py\n")
        f.write("kind,case,dim,block_size,order_by_dim,dt,scale,entries...\n")
        for row in rows:
            head = [str(v) for v in row[:5]]
            tail = [repr(float(v)) for v in row[5:]]
            f.write(",".join(head + tail) + "\n")
    print(f"wrote {out}: {len(rows)} rows")


if __name__ == "__main__":
    main()

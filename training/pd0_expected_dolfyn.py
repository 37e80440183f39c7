"""Expected values for estim-dvl's PD0 reader test, decoded by another reader (dolfyn).

Writes estim-dvl/tests/data/pd0_vmdas02_os_dolfyn.csv: every 25th ensemble of
shared/data/pd0/vmdas02_os.ENR and every ensemble with a bad bottom-track value (ensemble number, RTC time as Unix seconds, the four
bottom-track velocities in m/s and ranges in m, as dolfyn gives them: it keeps RDI's
-32.768 m/s bad-velocity marker in vel_bt, and a NaN is written as an empty cell), plus a
first comment line with the number of ensembles dolfyn read and its coordinate system.

Run (once, outside CI; dolfyn is never a test dependency):
    python3 -m venv /tmp/pd0venv
    /tmp/pd0venv/bin/pip install dolfyn==1.3.0 "numpy<2" "pandas<2.3" "xarray<2025" \
        "scipy<1.14" "netcdf4<1.7.3"
    /tmp/pd0venv/bin/python training/pd0_expected_dolfyn.py [DATA_DIR]
(dolfyn 1.3.0 still uses numpy.RankWarning, removed in numpy 2.)
"""

import math
import os
import sys

import dolfyn
import numpy as np

STRIDE = 25


def main():
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    data = sys.argv[1] if len(sys.argv) > 1 else os.environ.get(
        "ESTIM_DATA_DIR", os.path.join(root, "..", "shared", "data"))
    ds = dolfyn.read(os.path.join(data, "pd0", "vmdas02_os.ENR"))
    times = ds["time"].values.astype("datetime64[ns]").astype(np.int64) / 1e9
    number = ds["number"].values
    vel = ds["vel_bt"].values  # (4, n) m/s
    dist = ds["dist_bt"].values  # (4, n) m
    out = os.path.join(root, "estim-dvl", "tests", "data", "pd0_vmdas02_os_dolfyn.csv")

    def cell(x, decimals):
        return "" if math.isnan(x) else f"{x:.{decimals}f}"

    with open(out, "w") as f:
        f.write(f"# dolfyn {dolfyn.__version__}: {len(number)} ensembles, "
                f"coord_sys {ds.attrs['coord_sys']}\n")
        f.write("ensemble_number,time_unix_s,"
                + ",".join(f"bt_velocity_{i}_mps" for i in range(1, 5)) + ","
                + ",".join(f"bt_range_{i}_m" for i in range(1, 5)) + "\n")
        bad = (np.isnan(vel).any(axis=0) | np.isnan(dist).any(axis=0)
               | np.isclose(vel, -32.768).any(axis=0) | (dist == 0).any(axis=0))
        for k in range(len(number)):
            if k % STRIDE != 0 and not bad[k]:
                continue
            row = [str(int(number[k])), f"{times[k]:.3f}"]
            row += [cell(float(vel[i, k]), 4) for i in range(4)]
            row += [cell(float(dist[i, k]), 3) for i in range(4)]
            f.write(",".join(row) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

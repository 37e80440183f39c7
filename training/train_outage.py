"""Train OutageNet (IMU window + last valid DVL velocity + time since it -> body
velocity) on the dataset written by `estim dataset beamsnet` and export
models/NAME.onnx, models/NAME.json (metadata) and models/NAME_parity.json (NAME: --name,
default outage).

Examples: for each dataset row k (the target is the DVL velocity at t_k, the IMU window
the second before it) and `--pairs` earlier rows j of the same trajectory and
realization with 0 < t_k - t_j <= 60 s (drawn with a seeded generator), the last valid
velocity is the four-beam least-squares velocity pinv(A) beams_j (what a filter has when
the DVL drops out: the protocol's noisy beams) and the elapsed time is t_k - t_j.

Same rules as train_beamsnet.py: seeded, CPU, deterministic algorithms; trajectories 4
and 13 refused; the validation split may not separate trajectories that share rows.
R is the validation residual covariance over all elapsed times; `residual_std_by_elapsed`
(metadata `training`) holds the per-axis residual std in 10 s bins of elapsed time.
"""

import argparse
import json
import os
import platform
import sys
import time

import numpy as np
import torch
from torch import nn

from outage import WINDOW, OutageNet

ACC = slice(0, 300)
GYRO = slice(300, 600)
BEAMS = slice(600, 604)
TARGET = slice(604, 607)
TRAJ = 607
TIME = 608
REAL = 609
MAX_ELAPSED_S = 60.0


def parse_args():
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--dataset", required=True)
    p.add_argument("--out-dir", default="models")
    p.add_argument("--name", default="outage", help="output files NAME.onnx, NAME.json, NAME_parity.json")
    p.add_argument("--epochs", type=int, default=20)
    p.add_argument("--batch-size", type=int, default=128)
    p.add_argument("--lr", type=float, default=2e-3)
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--pairs", type=int, default=4)
    p.add_argument("--validation", default="3,10")
    p.add_argument(
        "--parity-inputs",
        choices=["validation", "synthetic"],
        default="validation",
        help="parity cases from the validation split, or seeded synthetic inputs (for a dataset of "
        "recorded IMU windows, which must not be committed)",
    )
    return p.parse_args()


def pairs(data, count, rng):
    """Indices (k, j) with j an earlier row of the same trajectory and realization, 0 < t_k - t_j <= 60 s."""
    key = data[:, TRAJ] * 100 + data[:, REAL]
    out_k, out_j = [], []
    for g in np.unique(key):
        rows = np.flatnonzero(key == g)
        rows = rows[np.argsort(data[rows, TIME])]
        t = data[rows, TIME]
        for a in range(1, len(rows)):
            lo = np.searchsorted(t, t[a] - MAX_ELAPSED_S - 1e-9, side="left")
            cand = np.arange(lo, a)
            if len(cand) == 0:
                continue
            pick = rng.choice(cand, size=min(count, len(cand)), replace=False)
            out_k.extend([rows[a]] * len(pick))
            out_j.extend(rows[pick])
    return np.asarray(out_k), np.asarray(out_j)


def main():
    args = parse_args()
    t0 = time.time()
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    torch.use_deterministic_algorithms(True)
    torch.set_num_threads(args.threads)

    data = np.load(args.dataset)
    with open(os.path.splitext(args.dataset)[0] + ".json") as f:
        meta = json.load(f)
    # The network must see the windows the filter feeds it (issue #30).
    if meta.get("window_alignment", {}).get("rule") != "filter":
        sys.exit(f"{args.dataset}: windows not aligned as the filter feeds them; rebuild it with `estim dataset beamsnet`")
    if data.ndim != 2 or data.shape[1] != meta["columns"]:
        sys.exit(f"{args.dataset}: shape {data.shape}, metadata says {meta['columns']} columns")
    traj = data[:, TRAJ].astype(int)
    for forbidden in (4, 13):
        if np.any(traj == forbidden):
            sys.exit(f"dataset holds trajectory {forbidden}: held-out test data, refusing to train")
    val_set = [int(x) for x in args.validation.split(",") if x]
    groups = meta.get("overlap_groups")
    if groups is None:
        sys.exit(f"{args.dataset}: metadata has no overlap_groups; rebuild it with `estim dataset beamsnet`")
    present = set(int(t) for t in np.unique(traj))
    for g in groups:
        members = [t for t in g if t in present]
        in_val = [t for t in members if t in val_set]
        if in_val and len(in_val) != len(members):
            sys.exit(f"validation {val_set} splits trajectories {members}, which share rows")

    geo = meta["beam_geometry"]
    theta = np.deg2rad(geo["theta_deg"])
    psi = np.deg2rad(np.asarray(geo["psi_deg"], dtype=float))
    a4 = np.stack([np.cos(psi) * np.sin(theta), np.sin(psi) * np.sin(theta), np.full(4, np.cos(theta))], axis=1)
    ls = data[:, BEAMS] @ np.linalg.pinv(a4).T

    k, j = pairs(data, args.pairs, rng)
    is_val = np.isin(traj[k], val_set)
    acc = data[:, ACC].reshape(-1, 3, WINDOW)
    gyro = data[:, GYRO].reshape(-1, 3, WINDOW)
    tr_rows = np.unique(k[~is_val])
    acc_mean, acc_std = acc[tr_rows].mean(axis=(0, 2)), acc[tr_rows].std(axis=(0, 2))
    gyro_mean, gyro_std = gyro[tr_rows].mean(axis=(0, 2)), gyro[tr_rows].std(axis=(0, 2))

    def tensors(sel):
        kk, jj = k[sel], j[sel]
        a = (acc[kk] - acc_mean[None, :, None]) / acc_std[None, :, None]
        g = (gyro[kk] - gyro_mean[None, :, None]) / gyro_std[None, :, None]
        elapsed = (data[kk, TIME] - data[jj, TIME])[:, None] / MAX_ELAPSED_S
        return (
            torch.tensor(a, dtype=torch.float32),
            torch.tensor(g, dtype=torch.float32),
            torch.tensor(ls[jj], dtype=torch.float32),
            torch.tensor(elapsed, dtype=torch.float32),
            torch.tensor(data[kk, TARGET], dtype=torch.float32),
        )

    tr = tensors(~is_val)
    va = tensors(is_val)
    print(f"examples: train {len(tr[0])}, validation {len(va[0])} (trajectories {val_set})", flush=True)
    model = OutageNet()
    opt = torch.optim.Adam(model.parameters(), lr=args.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=args.epochs, eta_min=args.lr * 1e-2)
    loss_fn = nn.MSELoss()
    gen = torch.Generator().manual_seed(args.seed)
    best = (float("inf"), None, -1)
    n = len(tr[0])
    for epoch in range(args.epochs):
        model.train()
        perm = torch.randperm(n, generator=gen)
        total = 0.0
        for i in range(0, n, args.batch_size):
            idx = perm[i : i + args.batch_size]
            opt.zero_grad()
            loss = loss_fn(model(tr[0][idx], tr[1][idx], tr[2][idx], tr[3][idx]), tr[4][idx])
            loss.backward()
            opt.step()
            total += loss.item() * len(idx)
        sched.step()
        model.eval()
        with torch.no_grad():
            vloss = loss_fn(model(*va[:4]), va[4]).item()
        if vloss < best[0]:
            best = (vloss, {kk: v.clone() for kk, v in model.state_dict().items()}, epoch)
        print(f"epoch {epoch:3d} train mse {total / n:.3e} val mse {vloss:.3e}", flush=True)
    model.load_state_dict(best[1])
    model.eval()
    print(f"best epoch {best[2]} (val mse {best[0]:.3e})")

    with torch.no_grad():
        pred = model(*va[:4])
        res = (pred - va[4]).double().numpy()
        blank = model(torch.zeros_like(va[0]), torch.zeros_like(va[1]), va[2], va[3])
    hold = (va[2] - va[4]).double().numpy()
    target = va[4].double().numpy()
    elapsed_s = va[3].double().numpy()[:, 0] * MAX_ELAPSED_S
    r = np.cov(res, rowvar=False)
    bins = []
    for lo in range(0, int(MAX_ELAPSED_S), 10):
        m = (elapsed_s > lo) & (elapsed_s <= lo + 10 + 1e-6)
        bins.append({
            "elapsed_s": [lo, lo + 10],
            "samples": int(m.sum()),
            "residual_std_mps": np.sqrt((res[m] ** 2).mean(axis=0)).tolist() if m.any() else None,
            "hold_last_rmse_mps": np.sqrt((hold[m] ** 2).mean(axis=0)).tolist() if m.any() else None,
        })
    imu_dependence = {
        "imu_replaced_rms_mps": (pred - blank).double().pow(2).mean(dim=0).sqrt().tolist(),
        "validation_rmse_per_axis_mps": np.sqrt((res**2).mean(axis=0)).tolist(),
        "validation_rmse_imu_replaced_per_axis_mps": np.sqrt(((blank.double().numpy() - target) ** 2).mean(axis=0)).tolist(),
        "validation_rmse_hold_last_velocity_per_axis_mps": np.sqrt((hold**2).mean(axis=0)).tolist(),
    }
    print(f"IMU dependence (validation): {imu_dependence}")
    for b in bins:
        print(f"elapsed {b['elapsed_s']}: residual std {b['residual_std_mps']}, hold-last rmse {b['hold_last_rmse_mps']}")

    os.makedirs(args.out_dir, exist_ok=True)
    onnx_name = f"{args.name}.onnx"
    onnx_path = os.path.join(args.out_dir, onnx_name)
    torch.onnx.export(
        model,
        (va[0][:2], va[1][:2], va[2][:2], va[3][:2]),
        onnx_path,
        input_names=["acc", "gyro", "last_velocity", "elapsed"],
        output_names=["velocity"],
        dynamic_axes={n_: {0: "batch"} for n_ in ["acc", "gyro", "last_velocity", "elapsed", "velocity"]},
        opset_version=13,
        do_constant_folding=True,
    )
    # Whether the dataset's IMU was recorded or synthesized (older datasets have no
    # `imu_source` and were synthesized).
    imu_source = meta.get("imu_source", "synthesized")
    imu_words = "" if imu_source == "synthesized" else f"{imu_source} IMU, "
    meta_out = {
        "format": "estim-learned-model/1",
        "imu_source": imu_source,
        "name": "OutageNet",
        "model": onnx_name,
        "inputs": [
            {"name": "acc", "stream": "acc", "channels": 3, "window": WINDOW, "sample_rate_hz": 100.0,
             "shape": [3, WINDOW], "mean": acc_mean.tolist(), "std": acc_std.tolist(),
             "unit": "m/s^2", "description": f"specific force, body frame, {imu_words}the 100 samples before the filter's update (DVL stamp shifted by the DVL time offset, dataset window_alignment)"},
            {"name": "gyro", "stream": "gyro", "channels": 3, "window": WINDOW, "sample_rate_hz": 100.0,
             "shape": [3, WINDOW], "mean": gyro_mean.tolist(), "std": gyro_std.tolist(),
             "unit": "rad/s", "description": "angular rate, body frame, same window as acc"},
            {"name": "last_velocity", "stream": "last_velocity", "channels": 3, "window": 1, "sample_rate_hz": 1.0,
             "shape": [3], "mean": [0.0] * 3, "std": [1.0] * 3,
             "unit": "m/s", "description": "the last valid DVL velocity (four-beam least squares), body frame"},
            {"name": "elapsed", "stream": "elapsed", "channels": 1, "window": 1, "sample_rate_hz": 1.0,
             "shape": [1], "mean": [0.0], "std": [MAX_ELAPSED_S],
             "unit": "s", "description": "time since the last valid DVL velocity (trained on 1-60 s)"},
        ],
        "output": {"name": "velocity", "size": 3, "unit": "m/s", "frame": "body (x forward, y right, z down)"},
        "noise_covariance": r.tolist(),
        "beam_geometry": meta["beam_geometry"],
        "beam_protocol": meta["beam_protocol"],
        "training": {
            "dataset": os.path.basename(args.dataset),
            "imu_source": imu_source,
            "dataset_metadata": meta,
            "max_elapsed_s": MAX_ELAPSED_S,
            "pairs_per_row": args.pairs,
            "residual_std_by_elapsed": bins,
            "train_trajectories": sorted(set(int(t) for t in np.unique(traj[k[~is_val]]))),
            "validation_trajectories": val_set,
            "validation_samples": int(len(va[0])),
            "train_samples": int(len(tr[0])),
            "best_epoch": best[2],
            "epochs": args.epochs,
            "batch_size": args.batch_size,
            "lr": args.lr,
            "seed": args.seed,
            "command": " ".join(["python"] + sys.argv),
            "torch": torch.__version__,
            "python": platform.python_version(),
            "duration_s": round(time.time() - t0, 1),
        },
        "imu_dependence": imu_dependence,
    }
    with open(os.path.join(args.out_dir, f"{args.name}.json"), "w") as f:
        json.dump(meta_out, f, indent=1)

    # Parity vectors: model-level (normalised) inputs and the PyTorch outputs in eval mode.
    description = "OutageNet inputs (already normalised, as fed to the ONNX graph) and PyTorch eval-mode outputs"
    if args.parity_inputs == "synthetic":
        # Recorded IMU windows stay out of the repository: standard normal normalised
        # windows (the training split's scale), last velocities around the A-KIT cruise
        # (2, 0, 0) m/s with the spread of the dataset's targets, and elapsed times
        # uniform in 1-60 s (divided by 60, as fed to the graph), from a generator of
        # their own (training is unaffected).
        g = torch.Generator().manual_seed(args.seed + 1)
        cnt = 4
        p_acc = torch.randn(cnt, 3, WINDOW, generator=g)
        p_gyro = torch.randn(cnt, 3, WINDOW, generator=g)
        p_last = torch.tensor([2.0, 0.0, 0.0]) + torch.randn(cnt, 3, generator=g) * torch.tensor([0.4, 0.3, 0.07])
        p_elapsed = (1.0 + (MAX_ELAPSED_S - 1.0) * torch.rand(cnt, 1, generator=g)) / MAX_ELAPSED_S
        description += "; seeded synthetic inputs (normal windows, last velocities, elapsed times), no recorded data"
    else:
        cnt = min(4, len(va[0]))
        rows = np.linspace(0, len(va[0]) - 1, cnt).astype(int)
        p_acc, p_gyro, p_last, p_elapsed = va[0][rows], va[1][rows], va[2][rows], va[3][rows]
    with torch.no_grad():
        out = model(p_acc, p_gyro, p_last, p_elapsed)
    parity = {
        "description": description,
        "cases": [
            {"acc": p_acc[jj].tolist(), "gyro": p_gyro[jj].tolist(), "last_velocity": p_last[jj].tolist(),
             "elapsed": p_elapsed[jj].tolist(), "velocity": out[jj].tolist()}
            for jj in range(cnt)
        ],
    }
    with open(os.path.join(args.out_dir, f"{args.name}_parity.json"), "w") as f:
        json.dump(parity, f)
    print(f"validation R diag sqrt: {np.sqrt(np.diag(r))}")
    print(f"wrote {onnx_path}, {args.name}.json, {args.name}_parity.json in {time.time() - t0:.1f} s")


if __name__ == "__main__":
    main()

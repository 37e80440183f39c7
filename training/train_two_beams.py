"""Train TwoBeamsNet (IMU window + beams 1 and 2 -> body velocity) on the dataset written
by `estim dataset beamsnet` and export models/NAME.onnx, models/NAME.json (metadata) and
models/NAME_parity.json (NAME: --name, default two_beams).

Same rules as train_beamsnet.py: seeded, CPU, deterministic algorithms; trajectories 4
and 13 refused; the validation split may not separate trajectories that share rows.
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

from two_beams import BEAMS, WINDOW, TwoBeamsNet

ACC = slice(0, 300)
GYRO = slice(300, 600)
BEAM_COLUMNS = [600, 601]  # beams 1 and 2 (azimuth 45 and 135 deg)
TARGET = slice(604, 607)
TRAJ = 607


def parse_args():
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--dataset", required=True)
    p.add_argument("--out-dir", default="models")
    p.add_argument("--name", default="two_beams", help="output files NAME.onnx, NAME.json, NAME_parity.json")
    p.add_argument("--epochs", type=int, default=30)
    p.add_argument("--batch-size", type=int, default=64)
    p.add_argument("--lr", type=float, default=2e-3)
    p.add_argument("--seed", type=int, default=5)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--validation", default="3,10")
    p.add_argument(
        "--parity-inputs",
        choices=["validation", "synthetic"],
        default="validation",
        help="parity cases from the validation split, or seeded synthetic inputs (for a dataset of "
        "recorded IMU windows, which must not be committed)",
    )
    return p.parse_args()


def main():
    args = parse_args()
    t0 = time.time()
    torch.manual_seed(args.seed)
    np.random.seed(args.seed)
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
    is_val = np.isin(traj, val_set)
    train, val = data[~is_val], data[is_val]
    print(f"samples: train {len(train)}, validation {len(val)} (trajectories {val_set})")

    acc = lambda d: d[:, ACC].reshape(-1, 3, WINDOW)
    gyro = lambda d: d[:, GYRO].reshape(-1, 3, WINDOW)
    acc_mean, acc_std = acc(train).mean(axis=(0, 2)), acc(train).std(axis=(0, 2))
    gyro_mean, gyro_std = gyro(train).mean(axis=(0, 2)), gyro(train).std(axis=(0, 2))

    def tensors(d):
        a = (acc(d) - acc_mean[None, :, None]) / acc_std[None, :, None]
        g = (gyro(d) - gyro_mean[None, :, None]) / gyro_std[None, :, None]
        return (
            torch.tensor(a, dtype=torch.float32),
            torch.tensor(g, dtype=torch.float32),
            torch.tensor(d[:, BEAM_COLUMNS], dtype=torch.float32),
            torch.tensor(d[:, TARGET], dtype=torch.float32),
        )

    tr = tensors(train)
    va = tensors(val)
    model = TwoBeamsNet()
    geo = meta["beam_geometry"]
    theta = np.deg2rad(geo["theta_deg"])
    psi = np.deg2rad(np.asarray(geo["psi_deg"], dtype=float))
    a4 = np.stack([np.cos(psi) * np.sin(theta), np.sin(psi) * np.sin(theta), np.full(4, np.cos(theta))], axis=1)
    a2 = a4[[c - 600 for c in BEAM_COLUMNS]]
    with torch.no_grad():
        model.linear.weight[:] = torch.tensor(np.linalg.pinv(a2), dtype=torch.float32)
        model.linear.bias.zero_()
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
            loss = loss_fn(model(tr[0][idx], tr[1][idx], tr[2][idx]), tr[3][idx])
            loss.backward()
            opt.step()
            total += loss.item() * len(idx)
        sched.step()
        model.eval()
        with torch.no_grad():
            vloss = loss_fn(model(va[0], va[1], va[2]), va[3]).item()
        if vloss < best[0]:
            best = (vloss, {k: v.clone() for k, v in model.state_dict().items()}, epoch)
        print(f"epoch {epoch:3d} train mse {total / n:.3e} val mse {vloss:.3e}", flush=True)
    model.load_state_dict(best[1])
    model.eval()
    print(f"best epoch {best[2]} (val mse {best[0]:.3e})")

    with torch.no_grad():
        pred = model(va[0], va[1], va[2])
        res = (pred - va[3]).double().numpy()
        blank = model(torch.zeros_like(va[0]), torch.zeros_like(va[1]), va[2])
        linear_only = (va[2].double() @ torch.tensor(np.linalg.pinv(a2)).T).numpy()
    r = np.cov(res, rowvar=False)
    target = va[3].double().numpy()
    imu_dependence = {
        "imu_replaced_rms_mps": (pred - blank).double().pow(2).mean(dim=0).sqrt().tolist(),
        "validation_rmse_per_axis_mps": np.sqrt((res**2).mean(axis=0)).tolist(),
        "validation_rmse_imu_replaced_per_axis_mps": np.sqrt(((blank.double().numpy() - target) ** 2).mean(axis=0)).tolist(),
        "validation_rmse_min_norm_two_beams_per_axis_mps": np.sqrt(((linear_only - target) ** 2).mean(axis=0)).tolist(),
    }
    print(f"IMU dependence (validation): {imu_dependence}")

    os.makedirs(args.out_dir, exist_ok=True)
    onnx_name = f"{args.name}.onnx"
    onnx_path = os.path.join(args.out_dir, onnx_name)
    torch.onnx.export(
        model,
        (va[0][:2], va[1][:2], va[2][:2]),
        onnx_path,
        input_names=["acc", "gyro", "beams"],
        output_names=["velocity"],
        dynamic_axes={"acc": {0: "batch"}, "gyro": {0: "batch"}, "beams": {0: "batch"}, "velocity": {0: "batch"}},
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
        "name": "TwoBeamsNet",
        "model": onnx_name,
        "inputs": [
            {"name": "acc", "stream": "acc", "channels": 3, "window": WINDOW, "sample_rate_hz": 100.0,
             "shape": [3, WINDOW], "mean": acc_mean.tolist(), "std": acc_std.tolist(),
             "unit": "m/s^2", "description": f"specific force, body frame, {imu_words}the 100 samples before the filter's update for the DVL sample (stamp shifted by the DVL time offset, dataset window_alignment)"},
            {"name": "gyro", "stream": "gyro", "channels": 3, "window": WINDOW, "sample_rate_hz": 100.0,
             "shape": [3, WINDOW], "mean": gyro_mean.tolist(), "std": gyro_std.tolist(),
             "unit": "rad/s", "description": "angular rate, body frame, same window as acc"},
            {"name": "beams", "stream": "beams", "channels": BEAMS, "window": 1, "sample_rate_hz": meta.get("dvl_rate_hz", 1.0),
             "shape": [BEAMS], "mean": [0.0] * BEAMS, "std": [1.0] * BEAMS,
             "unit": "m/s", "description": "DVL beams 1 and 2 (azimuth 45 and 135 deg) at the update time"},
        ],
        "output": {"name": "velocity", "size": 3, "unit": "m/s", "frame": "body (x forward, y right, z down)"},
        "noise_covariance": r.tolist(),
        "beam_geometry": meta["beam_geometry"],
        "beam_protocol": meta["beam_protocol"],
        "training": {
            "dataset": os.path.basename(args.dataset),
            "imu_source": imu_source,
            "dataset_metadata": meta,
            "beams_used": [c - 599 for c in BEAM_COLUMNS],
            "train_trajectories": sorted(set(int(t) for t in np.unique(traj[~is_val]))),
            "validation_trajectories": val_set,
            "validation_samples": int(len(val)),
            "train_samples": int(len(train)),
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
    description = "TwoBeamsNet inputs (already normalised, as fed to the ONNX graph) and PyTorch eval-mode outputs"
    if args.parity_inputs == "synthetic":
        # Recorded IMU windows stay out of the repository: standard normal normalised
        # windows (the training split's scale) and beams 1 and 2 of A v (1.007) for seeded
        # velocities, from a generator of their own (training is unaffected).
        g = torch.Generator().manual_seed(args.seed + 1)
        k = 4
        p_acc = torch.randn(k, 3, WINDOW, generator=g)
        p_gyro = torch.randn(k, 3, WINDOW, generator=g)
        v = torch.randn(k, 3, generator=g, dtype=torch.float64) * torch.tensor([1.0, 0.3, 0.1], dtype=torch.float64)
        p_beams = (1.007 * v @ torch.tensor(a2, dtype=torch.float64).T).float()
        description += "; seeded synthetic inputs (normal windows, beams 1 and 2 of seeded velocities), no recorded data"
    else:
        k = min(4, len(va[0]))
        rows = np.linspace(0, len(va[0]) - 1, k).astype(int)
        p_acc, p_gyro, p_beams = va[0][rows], va[1][rows], va[2][rows]
    with torch.no_grad():
        out = model(p_acc, p_gyro, p_beams)
    parity = {
        "description": description,
        "cases": [
            {"acc": p_acc[j].tolist(), "gyro": p_gyro[j].tolist(), "beams": p_beams[j].tolist(), "velocity": out[j].tolist()}
            for j in range(k)
        ],
    }
    with open(os.path.join(args.out_dir, f"{args.name}_parity.json"), "w") as f:
        json.dump(parity, f)
    print(f"validation R diag sqrt: {np.sqrt(np.diag(r))}")
    print(f"wrote {onnx_path}, {args.name}.json, {args.name}_parity.json in {time.time() - t0:.1f} s")


if __name__ == "__main__":
    main()

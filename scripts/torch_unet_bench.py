#!/usr/bin/env python3
"""Reference for `plumenet bench-net`: PlumeNet (DeepCFD's UNetEx) in PyTorch on the CPU.

Reads from DIR what `plumenet bench-net` exported: `inputs.npy` [N, C, H, W] (the bank's network
inputs), `outputs.npy` [N, 1, H, W] (Burn's raw outputs), `solid.npy` [H, W] and
`weights/<name>.npy` (one file per parameter, named by its module path, which is its
`state_dict` key here). The architecture is read off the weight shapes. Modes (each prints one
JSON object):

- `check`: loads the weights (every key and shape must match) and reports the largest
  difference between this network's bank and Burn's.
- `bank`: times the whole bank in forward passes of `--chunk` samples (as plumenet does).
- `train`: times training steps (forward, masked MSE, backward, AdamW with `--lr` and
  `--weight-decay`, which plumenet passes from its training defaults) on a batch of `--batch`
  inputs, after two warm-up steps.

Installs torch and numpy with pip when they are missing (only this benchmark needs Python).
Uses every core this process may run on (its CPU affinity, as plumenet's thread pool does).
"""
import argparse
import glob
import json
import os
import subprocess
import sys
import time

try:
    import numpy as np
    import torch
except ImportError:
    subprocess.check_call([sys.executable, "-m", "pip", "install", "--quiet", "numpy", "torch"])
    import numpy as np
    import torch

from torch import nn
from torch.nn import functional as F


class Block(nn.Module):
    """`count` same-padded convolutions with ReLU (plumenet's `ConvBlock`)."""

    def __init__(self, cin, cout, kernel, count):
        super().__init__()
        self.convs = nn.ModuleList(
            nn.Conv2d(cin if k == 0 else cout, cout, kernel, padding=kernel // 2) for k in range(count)
        )

    def forward(self, x):
        for conv in self.convs:
            x = F.relu(conv(x))
        return x


class PlumeNet(nn.Module):
    """UNetEx: encoder blocks with 2x2 max-pool, transposed-convolution up, skip concatenation,
    decoder blocks and a 1x1 head (plumenet's `PlumeNet`, same parameter names)."""

    def __init__(self, cin, filters, kernel, count):
        super().__init__()
        f = filters
        self.encoders = nn.ModuleList(
            Block(cin if l == 0 else f[l - 1], c, kernel, count) for l, c in enumerate(f)
        )
        self.ups = nn.ModuleList(
            nn.ConvTranspose2d(f[l + 1], f[l], 2, stride=2) for l in reversed(range(len(f) - 1))
        )
        self.decoders = nn.ModuleList(
            Block(2 * f[l], f[l], kernel, count) for l in reversed(range(len(f) - 1))
        )
        self.head = nn.Conv2d(f[0], 1, 1)

    def forward(self, x):
        skips = []
        for l, enc in enumerate(self.encoders):
            x = enc(x)
            if l + 1 < len(self.encoders):
                skips.append(x)
                x = F.max_pool2d(x, 2, 2)
        for up, dec in zip(self.ups, self.decoders):
            x = dec(torch.cat([up(x), skips.pop()], 1))
        return self.head(x)


def load(directory):
    """The network with plumenet's weights, its inputs, Burn's outputs and the free-cell mask."""
    weights = {
        os.path.basename(p)[: -len(".npy")]: torch.from_numpy(np.load(p))
        for p in glob.glob(os.path.join(directory, "weights", "*.npy"))
    }
    levels = 1 + max(int(k.split(".")[1]) for k in weights if k.startswith("encoders."))
    count = 1 + max(int(k.split(".")[3]) for k in weights if k.startswith("encoders.0.convs."))
    first = weights["encoders.0.convs.0.weight"]
    filters = [weights[f"encoders.{l}.convs.0.weight"].shape[0] for l in range(levels)]
    net = PlumeNet(first.shape[1], filters, first.shape[2], count)
    state = net.state_dict()
    if set(state) != set(weights):
        raise SystemExit(f"weight names differ: {sorted(set(state) ^ set(weights))}")
    for name, value in weights.items():
        if state[name].shape != value.shape:
            raise SystemExit(f"{name}: shape {tuple(value.shape)} != {tuple(state[name].shape)}")
    net.load_state_dict(weights)
    inputs = torch.from_numpy(np.load(os.path.join(directory, "inputs.npy")))
    outputs = torch.from_numpy(np.load(os.path.join(directory, "outputs.npy")))
    free = 1.0 - torch.from_numpy(np.load(os.path.join(directory, "solid.npy")))
    return net, inputs, outputs, free


def bank(net, inputs, chunk):
    with torch.inference_mode():
        return torch.cat([net(inputs[i : i + chunk]) for i in range(0, len(inputs), chunk)])


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("dir")
    parser.add_argument("--mode", choices=["check", "bank", "train"], required=True)
    parser.add_argument("--chunk", type=int, default=64)
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--steps", type=int, default=10)
    # No defaults: plumenet passes its own training defaults, the one place they are defined.
    parser.add_argument("--lr", type=float)
    parser.add_argument("--weight-decay", type=float)
    args = parser.parse_args()
    if args.mode == "train" and (args.lr is None or args.weight_decay is None):
        parser.error("--mode train needs --lr and --weight-decay")
    torch.set_num_threads(len(os.sched_getaffinity(0)))
    net, inputs, outputs, free = load(args.dir)
    report = {"torch": torch.__version__, "threads": torch.get_num_threads()}
    if args.mode == "check":
        net.eval()
        diff = (bank(net, inputs, args.chunk) - outputs).abs().max().item()
        report.update(max_abs_difference=diff, max_abs_output=outputs.abs().max().item())
    elif args.mode == "bank":
        net.eval()
        start = time.perf_counter()
        bank(net, inputs, args.chunk)
        report["seconds"] = time.perf_counter() - start
    else:
        net.train()
        x, y = inputs[: args.batch].clone(), outputs[: args.batch].clone()
        mask = free.expand_as(y).contiguous()
        optim = torch.optim.AdamW(net.parameters(), lr=args.lr, weight_decay=args.weight_decay)
        for step in range(args.steps + 2):
            if step == 2:
                start = time.perf_counter()
            optim.zero_grad(set_to_none=True)
            loss = ((net(x) - y) ** 2 * mask).sum() / mask.sum()
            loss.backward()
            optim.step()
            loss.item()
        report["seconds_per_step"] = (time.perf_counter() - start) / args.steps
    print(json.dumps(report))


if __name__ == "__main__":
    main()

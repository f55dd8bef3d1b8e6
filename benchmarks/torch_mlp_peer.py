#!/usr/bin/env python3
"""The PyTorch peer of ``throughput_mlp.py``: the same network, data and training step in PyTorch.

One step encodes the batch (``mlp_problem``: sin and cos of 2^k pi x, k < 10, 60 features), runs the
ReLU MLP 60-64-64-4 (``torch.nn.Linear``), takes the mean squared error against the targets,
backpropagates and updates by ``torch.optim.Adam`` (lr 1e-3, betas 0.9 / 0.999, eps 1e-8; ``fused``
on CUDA). Layers start uniform in +-1/sqrt(fan_in), biases 0 (the JAX peer's and drjit.nn's rule).
Two modes: ``eager``, and ``compile`` (the step's forward and loss through ``torch.compile``; a mode
that cannot compile here, for want of a C++ compiler or Triton, is reported as skipped with the reason).

Needs only numpy and torch: on a GPU machine, its own Python; on this CPU, a throw-away venv
(``python3 -m venv /tmp/torchenv && /tmp/torchenv/bin/pip install torch==2.13.0 numpy``, a CPU build).
``throughput_mlp.py --torch-python`` runs it. Alone:
    python3 benchmarks/torch_mlp_peer.py --batch-log2 14 16 18 --steps 10 [--device cuda]
Prints one JSON line per (mode, batch): ``{"impl": "torch eager", "batch": N, "median_step_s": ..., "pts_per_s": ...}``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mlp_problem import BETAS, DIMS, EPS, FREQS, LR, batch, flops_per_point  # noqa: E402


def build(torch, device: str, seed: int = 0):
    """The MLP (``torch.nn.Sequential``) with the peers' initialisation, and its Adam."""
    torch.manual_seed(seed)
    layers = []
    for i, (n_in, n_out) in enumerate(zip(DIMS[:-1], DIMS[1:])):
        linear = torch.nn.Linear(n_in, n_out, device=device)
        with torch.no_grad():
            linear.weight.uniform_(-1.0, 1.0).div_(np.sqrt(n_in))
            linear.bias.zero_()
        layers.append(linear)
        if i + 2 < len(DIMS):
            layers.append(torch.nn.ReLU())
    net = torch.nn.Sequential(*layers)
    opt = torch.optim.Adam(net.parameters(), lr=LR, betas=BETAS, eps=EPS, fused=device.startswith("cuda"))
    return net, opt


def make_loss(torch, net):
    """``loss(x, t)``: encoding, MLP and mean squared error."""
    angular = torch.pi * 2.0 ** torch.arange(FREQS, dtype=torch.float32, device=next(net.parameters()).device)

    def loss(x, t):
        phase = (x[:, :, None] * angular).reshape(x.shape[0], 3 * FREQS)
        return torch.mean(torch.square(net(torch.cat([torch.sin(phase), torch.cos(phase)], dim=1)) - t))

    return loss


def measure(torch, n: int, steps: int, device: str, compiled: bool) -> dict:
    """The median time of ``steps`` training steps on a batch of ``n`` (after 2 that compile and warm up)."""
    net, opt = build(torch, device)
    loss_fn = make_loss(torch, net)
    if compiled:
        loss_fn = torch.compile(loss_fn)
    xs, ts = batch(n)
    x, t = torch.from_numpy(xs).to(device), torch.from_numpy(ts).to(device)
    times, losses = [], []
    for _ in range(steps + 2):
        start = time.perf_counter()
        opt.zero_grad(set_to_none=True)
        value = loss_fn(x, t)
        value.backward()
        opt.step()
        losses.append(float(value.detach()))  # waits for the step
        times.append(time.perf_counter() - start)
    median = float(np.median(times[2:]))
    return {"impl": f"torch {'compile' if compiled else 'eager'}", "torch": torch.__version__, "device": device,
            "threads": torch.get_num_threads(), "batch": n, "dims": list(DIMS), "median_step_s": median,
            "pts_per_s": n / median, "gflops": flops_per_point() * n / median / 1e9,
            "loss_first": losses[0], "loss_last": losses[-1]}


def main() -> int:
    import torch

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch-log2", type=int, nargs="+", default=[14, 16, 18])
    ap.add_argument("--steps", type=int, default=10, help="timed steps per batch size (after 2 warm-up steps)")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--modes", nargs="+", choices=("eager", "compile"), default=["eager", "compile"])
    args = ap.parse_args()
    for mode in args.modes:
        for log2 in args.batch_log2:
            try:
                line = measure(torch, 2**log2, args.steps, args.device, compiled=mode == "compile")
            except Exception as exc:  # torch.compile without a compiler or Triton: say so, measure the rest
                if mode != "compile":
                    raise
                line = {"impl": "torch compile", "batch": 2**log2, "skipped": f"{type(exc).__name__}: {str(exc)[:200]}"}
            print(json.dumps(line), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

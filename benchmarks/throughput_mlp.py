#!/usr/bin/env python3
"""Network training throughput: mitsnerf's Dr.Jit MLPs against JAX and PyTorch peers, and this CPU's peak.

The problem (``mlp_problem.py``, shared with the peers): x in [0, 1)^3 -> [sin(2^k pi x), cos(2^k pi x)],
k < 10 (60 features) -> 2 hidden layers of 64, ReLU -> 4 outputs; one step is the encoding, forward,
MSE against 4 smooth targets, backward and an Adam update (lr 1e-3) on the same synthetic batch
(seed 0). The peers are ``jax_mlp_peer.py`` (``jax.jit``) and ``torch_mlp_peer.py`` (eager and
``torch.compile``), each in its own Python. mitsnerf's paths (``--paths``):

- ``channel-major``: ``drjit.nn.Sequential`` on (C, N) tensors (``SinEncode`` + ``Linear``), as the
  ``nerf`` field evaluates its network; the encoding's frequencies match the peer's (x / 2 in);
- ``channel-major frozen``: the same step recorded by ``dr.freeze`` and replayed;
- ``point-major``: ``mitsnerf.fields.mlp.dense_apply`` on (N, C) tensors (``X W + b``), one product per
  layer (``slices=0``); the encoding from ``dr.sin``/``dr.cos`` on each coordinate;
- ``point-major split-k``: the same network in ``SPLIT_K`` (64) split-k batches (``dense_apply(...,
  slices=64)``: each layer's weights gathered into 64 copies, the points into as many batches, ``(S, N/S, C) x
  (S, C, D)``, so that the weight gradient is S products over N/S points each in one launch), as the ``ngp``
  field multiplies on CUDA since the second GPU run found it 7.5x faster there than one product;
- ``coopvec fp32`` / ``coopvec fp16``: the same ``Sequential`` on cooperative vectors (``nn.CoopVec``),
  weights packed by ``nn.pack(layout="training")``; fp16 casts after the encoding. On CUDA these run
  on the tensor cores; on the LLVM backend they are a reference path, 4-5x slower than tensor mode.

FLOPs per point are the peer's count, 3 x 2 x sum(d_i d_{i+1}) (forward, and twice that backward);
the peak is measured as numpy's float32 matrix product of two 4096^2 matrices (the roof any MLP
here can reach), and again on the network's own products at each batch (``layer_gemm_flops``: the
thin shapes a BLAS runs slower), and a nominal figure is printed from the core count, clock and SIMD width
(assuming two FMA units per core; stated as such). On CUDA these CPU roofs mean nothing: pass ``--no-peak``.

Set-up for the peers on this CPU (throw-away venvs, once): ``python3 -m venv /tmp/jaxenv &&
/tmp/jaxenv/bin/pip install "jax[cpu]==0.10.2"``; ``python3 -m venv /tmp/torchenv &&
/tmp/torchenv/bin/pip install torch==2.13.0 numpy``. On a GPU machine whose Python has both, pass it
to both flags. Run (only on an otherwise idle machine):
    .venv/bin/python benchmarks/throughput_mlp.py [--batch-log2 14 16 18] [--jax-python /tmp/jaxenv/bin/python]
        [--torch-python /tmp/torchenv/bin/python] [--paths ...]
Prints one JSON line per (path, batch), the peers' lines, and a summary with the ratios to each peer
(to torch: its faster mode at that batch).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import mitsnerf  # noqa: F401  (libLLVM before drjit)
from mitsnerf import env

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mlp_problem import DIMS, FREQS, LR, batch, flops_per_point  # noqa: E402

PEER = Path(__file__).resolve().parent / "jax_mlp_peer.py"
TORCH_PEER = Path(__file__).resolve().parent / "torch_mlp_peer.py"


def sgemm_flops(n: int = 4096, repeats: int = 5) -> float:
    a = np.random.default_rng(0).random((n, n), dtype=np.float32)
    b = np.random.default_rng(1).random((n, n), dtype=np.float32)
    a @ b
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        a @ b
        times.append(time.perf_counter() - t0)
    return 2.0 * n**3 / float(np.median(times))


def layer_gemm_flops(n: int, repeats: int = 5) -> float:
    """numpy's float32 FLOP/s on this network's own products at batch ``n``: every layer's forward
    ``W X`` and backward ``W^T dY``, ``dY X^T`` (channel-major shapes, ``DIMS``), the time summed.
    What a BLAS reaches on these thin shapes (inner dimension 60-64) rather than on square ones."""
    rng = np.random.default_rng(0)
    total_flops, total_s = 0.0, 0.0
    for c_in, c_out in zip(DIMS[:-1], DIMS[1:]):
        w = rng.random((c_out, c_in), dtype=np.float32)
        x = rng.random((c_in, n), dtype=np.float32)
        dy = rng.random((c_out, n), dtype=np.float32)
        products = (lambda w=w, x=x: w @ x, lambda w=w, dy=dy: w.T @ dy, lambda dy=dy, x=x: dy @ x.T)
        for product in products:  # each timed in the iteration that made it (bound all the same)
            product()
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                product()
                times.append(time.perf_counter() - t0)
            total_flops += 2.0 * c_in * c_out * n
            total_s += float(np.median(times))
    return total_flops / total_s


def nominal_flops() -> tuple[float | None, str]:
    """cores x max clock x FP32 FLOP/cycle (2 FMA units x SIMD lanes x 2), from /proc/cpuinfo and lscpu."""
    try:
        info = Path("/proc/cpuinfo").read_text()
    except OSError:
        return None, "no /proc/cpuinfo"
    flags = next((line.split(":", 1)[1].split() for line in info.splitlines() if line.startswith("flags")), [])
    lanes = 16 if "avx512f" in flags else 8 if "avx2" in flags else 4
    mhz = None
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
        for line in out.splitlines():
            if line.startswith("CPU max MHz:"):
                mhz = float(line.split(":")[1])
    except (OSError, subprocess.SubprocessError, ValueError):
        pass
    if mhz is None:
        values = [float(line.split(":")[1]) for line in info.splitlines() if line.startswith("cpu MHz")]
        mhz = max(values) if values else None
    if mhz is None:
        return None, "no clock found"
    cores = os.cpu_count() or 1
    per_cycle = 2 * lanes * 2
    return cores * mhz * 1e6 * per_cycle, (f"{cores} cores x {mhz:.0f} MHz x {per_cycle} FLOP/cycle "
                                           f"(2 FMA units x {lanes} lanes, assumed)")


def time_steps(step, steps: int) -> float:
    step()
    step()  # compilation, first Adam moments
    times = []
    for _ in range(steps):
        t0 = time.perf_counter()
        step()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def channel_major_problem(n: int):
    """``(net, opt, x, t)``: ``drjit.nn.Sequential`` on (C, N) tensors, as the ``nerf`` field evaluates it."""
    import drjit as dr
    import drjit.nn as nn
    import drjit.opt  # noqa: F401
    import mitsuba as mi

    net = nn.Sequential(nn.SinEncode(FREQS), nn.Linear(-1, DIMS[1]), nn.ReLU(), nn.Linear(-1, DIMS[2]), nn.ReLU(),
                        nn.Linear(-1, DIMS[3])).alloc(mi.TensorXf, 3, dr.rng(seed=0))
    xn, tn = batch(n)
    x = mi.TensorXf(np.ascontiguousarray(xn.T / 2))  # sin(2 pi 2^k (x/2)) = sin(2^k pi x): the peer's frequencies
    t = mi.TensorXf(np.ascontiguousarray(tn.T))
    opt = dr.opt.Adam(lr=LR)
    for key, value in net.items():
        opt[key] = value
    return net, opt, x, t


def channel_major_step(net, opt, x, t):
    """One training step: the optimiser's parameters into the network, MSE, backward, Adam; the loss."""
    import drjit as dr

    for key in opt.keys():
        net[key] = opt[key]
    loss = dr.mean(dr.square(net(x) - t), axis=None)
    dr.backward(loss)
    opt.step()
    return loss


def channel_major(n: int, steps: int, frozen: bool = False, profile: dict | None = None) -> float:
    """Median seconds per step; ``frozen``: the step recorded once by ``dr.freeze`` and replayed (no
    Python tracing or kernel compilation after the first calls); ``profile``: filled by :func:`kernel_profile`."""
    import drjit as dr

    net, opt, x, t = channel_major_problem(n)
    body = dr.freeze(channel_major_step) if frozen else channel_major_step

    def step() -> float:
        return body(net, opt, x, t).item()

    med = time_steps(step, steps)
    if profile is not None:
        profile.update(kernel_profile(step, steps))
    return med


def kernel_profile(step, steps: int) -> dict:
    """Where a step's wall time goes: Dr.Jit's kernel history over ``steps`` more steps gives the kernels
    launched per step and their execution time; the rest of the wall time is Python, tracing, code
    generation (cached after the first step) and launch overhead."""
    import drjit as dr

    dr.kernel_history()  # clear
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    t0 = time.perf_counter()
    for _ in range(steps):
        step()
    wall = (time.perf_counter() - t0) / steps
    history = dr.kernel_history()
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    kernel_s = sum(k.get("execution_time", 0.0) for k in history) / 1e3 / steps
    gemm = [k for k in history if k.get("type") == dr.KernelType.BatchedGemm]
    gemm_s = sum(k.get("execution_time", 0.0) for k in gemm) / 1e3 / steps
    return {"wall_s": wall, "kernels_per_step": len(history) / steps, "kernel_s": kernel_s,
            "kernel_fraction": kernel_s / wall, "other_s": wall - kernel_s,
            "gemm_tasks_per_step": len(gemm) / steps, "gemm_s": gemm_s, "gemm_fraction": gemm_s / wall}


def coopvec_problem(n: int, half: bool):
    """``(net, opt, xs, ts, Float)``: ``drjit.nn.Sequential`` on cooperative vectors (``nn.CoopVec``), its
    weights packed in the training layout by ``nn.pack``; ``half``: fp16 weights and activations after the
    encoding (``nn.Cast``), the loss in fp32. On CUDA the matrix-vector products run on the tensor cores."""
    import drjit as dr
    import drjit.nn as nn
    import drjit.opt  # noqa: F401
    import mitsuba as mi

    Float16 = dr.float16_array_t(mi.Float)
    cast = [nn.Cast(Float16)] if half else []
    net = nn.Sequential(nn.SinEncode(FREQS), *cast, nn.Linear(-1, DIMS[1]), nn.ReLU(), nn.Linear(-1, DIMS[2]),
                        nn.ReLU(), nn.Linear(-1, DIMS[3])).alloc(dr.tensor_t(Float16) if half else mi.TensorXf, 3,
                                                                 dr.rng(seed=0))
    packed = nn.pack(net, layout="training")
    net = packed[-1] if isinstance(packed, tuple) else packed  # (buffer, module) in some drjit releases
    xn, tn = batch(n)
    xs = [mi.Float(np.ascontiguousarray(xn[:, c] / 2)) for c in range(3)]  # the peer's frequencies (x / 2 in)
    ts = [mi.Float(np.ascontiguousarray(tn[:, c])) for c in range(DIMS[-1])]
    opt = dr.opt.Adam(lr=LR)
    opt.update(net)
    return net, opt, xs, ts, mi.Float


def coopvec(n: int, steps: int, half: bool) -> float:
    """Median seconds per step of the cooperative-vector path (fp16 weights if ``half``)."""
    import drjit as dr
    import drjit.nn as nn

    net, opt, xs, ts, Float = coopvec_problem(n, half)

    def step() -> float:
        net.update(opt)
        out = net(nn.CoopVec(*xs))
        loss = sum(dr.mean(dr.square(Float(o) - t)) for o, t in zip(out, ts)) / len(ts)
        dr.backward(loss)
        opt.step()
        return loss.item()

    return time_steps(step, steps)


def point_major(n: int, steps: int, slices: int = 0) -> float:
    import drjit as dr
    import drjit.opt  # noqa: F401
    import mitsuba as mi

    from mitsnerf.fields.mlp import dense_apply, dense_init, rows_tensor

    params = dense_init(list(DIMS), mi.TensorXf, dr.rng(seed=0), prefix="mlp.")
    xn, tn = batch(n)
    xs = [mi.Float(np.ascontiguousarray(xn[:, c])) for c in range(3)]
    t = mi.TensorXf(np.ascontiguousarray(tn))
    opt = dr.opt.Adam(lr=LR)
    for key, value in params.items():
        opt[key] = value

    def step() -> float:
        params.update({key: opt[key] for key in opt.keys()})
        rows = []
        for c in range(3):
            for k in range(FREQS):
                a = xs[c] * (2.0**k * math.pi)
                rows += [dr.sin(a), dr.cos(a)]
        x = rows_tensor(mi.TensorXf, rows, n)
        y = dense_apply(params, "mlp.", len(DIMS) - 1, x, slices=slices)
        loss = dr.mean(dr.square(y - t), axis=None)
        dr.backward(loss)
        opt.step()
        return loss.item()

    return time_steps(step, steps)


#: Point batches of the ``point-major split-k`` path (each of N / SPLIT_K points).
SPLIT_K = 64

PATHS = {
    "channel-major": lambda n, s, p: channel_major(n, s, profile=p),
    "channel-major frozen": lambda n, s, p: channel_major(n, s, frozen=True, profile=p),
    "point-major": lambda n, s, p: point_major(n, s, slices=0),
    "point-major split-k": lambda n, s, p: point_major(n, s, slices=min(SPLIT_K, n)),
    "coopvec fp32": lambda n, s, p: coopvec(n, s, half=False),
    "coopvec fp16": lambda n, s, p: coopvec(n, s, half=True),
}


def run_peer(python: str, script: Path, logs: list[int], steps: int) -> list[dict]:
    """The peer's JSON lines (its own Python, which need not have mitsnerf)."""
    cmd = [python, str(script), "--batch-log2", *map(str, logs), "--steps", str(steps)]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    return [json.loads(line) for line in out.splitlines() if line.startswith("{")]


def peers(args) -> dict[str, dict[int, float]]:
    """Each peer's best points/s per batch (``jax``; ``torch``: the faster of eager and compiled), its lines printed."""
    best: dict[str, dict[int, float]] = {}
    for name, python, script in (("jax", args.jax_python, PEER), ("torch", args.torch_python, TORCH_PEER)):
        if not Path(python).exists():
            print(json.dumps({"impl": name, "skipped": f"no {python}"}), flush=True)
            continue
        if subprocess.run([python, "-c", f"import {name}"], capture_output=True).returncode != 0:
            print(json.dumps({"impl": name, "skipped": f"{python} cannot import {name}"}), flush=True)
            continue
        for line in run_peer(python, script, args.batch_log2, args.steps):
            print(json.dumps(line), flush=True)
            if "pts_per_s" in line:
                batch_best = best.setdefault(name, {})
                batch_best[int(line["batch"])] = max(batch_best.get(int(line["batch"]), 0.0), float(line["pts_per_s"]))
    return best


def ours(args, variant: str, fpp: int) -> dict[tuple[str, int], float]:
    """mitsnerf's points/s per (path, batch), each line printed."""
    import drjit as dr
    import mitsuba as mi

    from mitsnerf.fields.mlp import usable_network_paths

    missing = [name for name in args.paths
               if name.startswith("coopvec") and name.replace(" ", "-") not in usable_network_paths(mi.TensorXf)]
    for name in missing:  # CUDA: no fp32 cooperative vectors in drjit 1.5
        print(json.dumps({"impl": f"mitsnerf {name}", "skipped": f"not available on {variant}"}), flush=True)
    measured: dict[tuple[str, int], float] = {}
    for logn in args.batch_log2:
        n = 2**logn
        for name in (p for p in args.paths if p not in missing):
            profile: dict = {}
            med = PATHS[name](n, args.steps, profile if args.profile else None)
            measured[(name, n)] = n / med
            print(json.dumps({"bench": "mlp", "impl": f"mitsnerf {name}", "batch": n, "dims": list(DIMS),
                              "median_step_s": med, "pts_per_s": n / med, "gflops": fpp * n / med / 1e9,
                              "threads": dr.thread_count(), "variant": variant,
                              **({"profile": profile} if profile else {})}), flush=True)
    return measured


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch-log2", type=int, nargs="+", default=[14, 16, 18])
    ap.add_argument("--steps", type=int, default=10, help="timed steps per batch size (after 2 warm-up steps)")
    ap.add_argument("--paths", nargs="+", choices=list(PATHS), default=list(PATHS), help="mitsnerf's paths to time")
    ap.add_argument("--jax-python", default="/tmp/jaxenv/bin/python",
                    help="a Python with jax installed (skipped if missing)")
    ap.add_argument("--torch-python", default="/tmp/torchenv/bin/python",
                    help="a Python with torch installed (skipped if missing)")
    ap.add_argument("--no-peak", action="store_true", help="skip the numpy matmul roof (a few seconds)")
    ap.add_argument("--profile", action="store_true",
                    help="also the channel-major paths' kernels per step and time inside kernels "
                         "(Dr.Jit's kernel history)")
    args = ap.parse_args()
    variant = env.set_variant()
    fpp = flops_per_point()
    measured = ours(args, variant, fpp)
    best = peers(args)
    roof = None if args.no_peak else sgemm_flops()
    layer_roof = {} if args.no_peak else {n: layer_gemm_flops(n) for n in {2**k for k in args.batch_log2}}
    cuda = variant.startswith("cuda")
    nominal, how = (None, "a CPU's formula: not computed on CUDA") if cuda else nominal_flops()
    for (name, n), pts in measured.items():
        ratios = {f"ratio_to_{peer}": pts / by_batch[n] if n in by_batch else None for peer, by_batch in best.items()}
        print(json.dumps({"summary": f"mitsnerf {name}", "batch": n, "pts_per_s": pts, **ratios,
                          "fraction_of_sgemm_roof": pts * fpp / roof if roof else None,
                          "fraction_of_layer_gemm_roof": pts * fpp / layer_roof[n] if layer_roof else None,
                          "layer_gemm_roof_gflops": layer_roof[n] / 1e9 if layer_roof else None,
                          "fraction_of_nominal_peak": pts * fpp / nominal if nominal else None}), flush=True)
    print(json.dumps({"flops_per_point": fpp, "sgemm_roof_gflops": roof / 1e9 if roof else None,
                      "nominal_peak_gflops": nominal / 1e9 if nominal else None, "nominal_rule": how}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

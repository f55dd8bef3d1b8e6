#!/usr/bin/env python3
"""The JAX peer of ``throughput_mlp.py``: the same network, data and training step in JAX, jit-compiled.

One step (``train_step``, a single ``jax.jit`` function) encodes the batch (``mlp_problem``: sin and
cos of 2^k pi x, k < 10, 60 features), runs the ReLU MLP 60-64-64-4, takes the mean squared error
against the targets, its gradient by ``jax.value_and_grad``, and an Adam update (lr 1e-3, betas
0.9 / 0.999, eps 1e-8, bias-corrected). The parameters and Adam's moments are donated to the step,
so they stay in place from one step to the next. Layers start uniform in +-1/sqrt(fan_in), biases 0.

Needs only numpy and JAX (a throw-away venv: ``python3 -m venv /tmp/jaxenv &&
/tmp/jaxenv/bin/pip install "jax[cpu]==0.10.2"``); ``throughput_mlp.py --jax-python`` runs it. Alone:
    /tmp/jaxenv/bin/python benchmarks/jax_mlp_peer.py --batch-log2 14 16 18 --steps 10
Prints one JSON line per batch size: ``{"impl": "jax", "batch": N, "median_step_s": ..., "pts_per_s": ...}``.
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


def make_step(jax, jnp):
    """The jitted ``train_step(params, adam, x, t) -> (params, adam, loss)``."""
    angular = jnp.pi * 2.0 ** jnp.arange(FREQS, dtype=jnp.float32)  # 2^k pi

    def features(x):
        phase = (x[:, :, None] * angular).reshape(x.shape[0], 3 * FREQS)
        return jnp.concatenate([jnp.sin(phase), jnp.cos(phase)], axis=1)

    def predict(params, x):
        h = features(x)
        *hidden, last = params
        for w, b in hidden:
            h = jax.nn.relu(h @ w + b)
        return h @ last[0] + last[1]

    def loss(params, x, t):
        return jnp.mean(jnp.square(predict(params, x) - t))

    def adam(params, grads, state):
        count, first, second = state
        count = count + 1
        first = jax.tree_util.tree_map(lambda m, g: BETAS[0] * m + (1.0 - BETAS[0]) * g, first, grads)
        second = jax.tree_util.tree_map(lambda v, g: BETAS[1] * v + (1.0 - BETAS[1]) * g * g, second, grads)
        rate = LR * jnp.sqrt(1.0 - BETAS[1] ** count) / (1.0 - BETAS[0] ** count)
        params = jax.tree_util.tree_map(lambda p, m, v: p - rate * m / (jnp.sqrt(v) + EPS), params, first, second)
        return params, (count, first, second)

    def train_step(params, state, x, t):
        value, grads = jax.value_and_grad(loss)(params, x, t)
        params, state = adam(params, grads, state)
        return params, state, value

    return jax.jit(train_step, donate_argnums=(0, 1))


def initial(jax, jnp, seed: int = 0):
    """Layers uniform in +-1/sqrt(fan_in) (drjit.nn.Linear's rule), zero biases; Adam's zero moments."""
    keys = jax.random.split(jax.random.PRNGKey(seed), len(DIMS) - 1)
    params = tuple((jax.random.uniform(k, (n_in, n_out), jnp.float32, -1.0, 1.0) / np.sqrt(n_in),
                    jnp.zeros(n_out, jnp.float32)) for k, n_in, n_out in zip(keys, DIMS[:-1], DIMS[1:]))
    moments = lambda: jax.tree_util.tree_map(jnp.zeros_like, params)  # noqa: E731  (two buffers: both are donated)
    return params, (jnp.float32(0.0), moments(), moments())


def measure(n: int, steps: int) -> dict:
    """The median time of ``steps`` training steps on a batch of ``n`` (after 2 that compile and warm up)."""
    import jax
    import jax.numpy as jnp

    step = make_step(jax, jnp)
    params, state = initial(jax, jnp)
    xs, ts = batch(n)
    x, t = jnp.asarray(xs), jnp.asarray(ts)
    times, losses = [], []
    for _ in range(steps + 2):
        start = time.perf_counter()
        params, state, value = step(params, state, x, t)
        losses.append(float(value))  # waits for the step
        times.append(time.perf_counter() - start)
    median = float(np.median(times[2:]))
    return {"impl": "jax", "jax": jax.__version__, "backend": jax.default_backend(), "batch": n, "dims": list(DIMS),
            "median_step_s": median, "pts_per_s": n / median, "gflops": flops_per_point() * n / median / 1e9,
            "loss_first": losses[0], "loss_last": losses[-1]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch-log2", type=int, nargs="+", default=[14, 16, 18])
    ap.add_argument("--steps", type=int, default=10, help="timed steps per batch size (after 2 warm-up steps)")
    args = ap.parse_args()
    for log2 in args.batch_log2:
        print(json.dumps(measure(2**log2, args.steps)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Small fully connected networks on point-major tensors: ``Y = X W + b`` with X of shape (M, C),
and the choice of how a field evaluates its network (:func:`network_path`).

``drjit.nn.Linear`` evaluates ``W X`` on channel-major (C, M) tensors. On the LLVM
backend the point-major product ``X W`` measured 2-4x faster for the narrow layers
of the ngp field (e.g. (2^18, 24) x (24, 64): 17 ms against 75 ms forward), so these
networks keep points in rows. Weights are ``(C_in, C_out)`` tensors, biases
``(C_out,)``; initialisation is uniform Xavier as ``drjit.nn.Linear``'s
(``U[-k, k]``, ``k = 1 / sqrt(C_out)``) from a seeded generator.
"""

from __future__ import annotations

import sys

import drjit as dr
import drjit.nn as nn

NETWORK_PATHS = ("auto", "tensor", "coopvec-fp32", "coopvec-fp16")
"""How a field evaluates its layers: on tensors (its own layout), on ``drjit.nn`` cooperative vectors
in fp32 or fp16 (on CUDA, the tensor cores; fp16's training gradients are wrong, :func:`network_path`),
or ``auto`` (:func:`network_path`)."""


def network_path(requested: str, TensorXf) -> str:
    """The path ``requested`` (a :data:`NETWORK_PATHS` entry) resolves to on ``TensorXf``'s backend.

    ``auto`` is ``tensor`` on every backend for now. On the LLVM backend tensors measured 4-5x faster
    than cooperative vectors in fp32 on the 2-core CPU, and fp16 slower again (docs/notes/mlp.md,
    "Cooperative vectors and a PyTorch peer"). On CUDA, Dr.Jit runs fp16 cooperative vectors on the
    tensor cores: an H200 ran the MLP's training step 64x faster on them than on tensors at 2^20 points
    (docs/notes/gpu-runs.md), but fp16 does not train: Dr.Jit 1.5 sums a layer's weight gradient
    over the batch in fp16 and rounds each point's gradient to fp16, so at a training batch (2^17 points,
    each adding ~1e-6) the weight gradients come out 30-75% wrong, signs included, and the hash grid's
    27% (on LLVM as on CUDA; tests/fields/test_network_paths.py), and nerf on fp16 never left the empty box
    on an H200 (17.2 dB on medium pixels where tensors reached 43.1), nor did ngp (24.7 dB where tensors reached
    44.8, and 1.35x slower than tensors with split-k, :data:`CUDA_SPLIT_K`). Loss scaling (x4096) with the batch in
    16 separately packed slices brought them within 1.2% on LLVM, not yet built into the fields. ``auto``
    moves to a path only once a GPU run has measured it faster at the same quality. Name a path to use one.

    A path the backend lacks (:func:`usable_network_paths`) is a :class:`mitsnerf.errors.SpecError` naming
    ``network.network_path`` (the key in the methods' configs) and the paths it has.

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> network_path("auto", mi.TensorXf), network_path("coopvec-fp32", mi.TensorXf)
    ('tensor', 'coopvec-fp32')
    """
    if requested not in NETWORK_PATHS:
        raise ValueError(f"network_path: must be one of {', '.join(NETWORK_PATHS)}, got {requested!r}")
    usable = usable_network_paths(TensorXf)
    if requested not in usable:
        from mitsnerf.errors import SpecError

        raise SpecError(None, "network.network_path", f"{requested} is not available on {dr.backend_v(TensorXf).name}: "
                        f"{_MISSING[requested]}; use one of {', '.join(usable)}")
    return "tensor" if requested == "auto" else requested


#: Why a path is missing on CUDA (drjit 1.5, seen on an H200: ``jit_coop_vec_compute_layout(): CUDA/OptiX
#: conversion to optimal layout is currently limited to half precision data`` when a run renders its views).
_MISSING = {"coopvec-fp32": "Dr.Jit packs matrices into the layouts cooperative vectors need there in fp16 only"}


def usable_network_paths(TensorXf) -> tuple[str, ...]:
    """The :data:`NETWORK_PATHS` that ``TensorXf``'s backend runs (on CUDA, no ``coopvec-fp32``).

    >>> import drjit as dr
    >>> usable_network_paths(dr.llvm.ad.TensorXf), usable_network_paths(dr.cuda.ad.TensorXf)
    (('auto', 'tensor', 'coopvec-fp32', 'coopvec-fp16'), ('auto', 'tensor', 'coopvec-fp16'))
    """
    if dr.backend_v(TensorXf) == dr.JitBackend.CUDA:
        return tuple(p for p in NETWORK_PATHS if p not in _MISSING)
    return NETWORK_PATHS


def pack_layers(tensors, half: bool) -> list:
    """Views of fp32 weight and bias ``tensors`` packed (``nn.pack``, training layout) for ``nn.matvec``;
    ``half``: of fp16 copies. Gradients flow back through the packing to the fp32 tensors.

    Inside ``dr.suspend_grad()`` the tensors are detached first: drjit 1.5 aborts the process when
    ``nn.pack`` meets tensors whose gradients are enabled but suspended (an occupancy grid's update).
    """
    tensors = [t if dr.grad_enabled(t) else dr.detach(t) for t in tensors]
    if half:
        Half = dr.tensor_t(dr.float16_array_t(dr.leaf_t(type(tensors[0]))))
        tensors = [Half(t) for t in tensors]
    return list(nn.pack(*tensors, layout="training"))


def dense_apply_coop(params, prefix: str, n_layers: int, x, half: bool = False):
    """:func:`dense_apply` on a cooperative vector ``x`` (``nn.CoopVec`` of C_in Floats) -> C_out Floats.

    The same (C_in, C_out) weights, packed each call (:func:`pack_layers`) and applied transposed
    (``nn.matvec(W, x, b, transpose=True)`` is ``W^T x + b``, one point's ``x W + b``); ReLU between
    layers; ``half``: in fp16, the outputs cast back to fp32.

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> p = dense_init([3, 8, 2], mi.TensorXf, dr.rng(seed=0))
    >>> len(dense_apply_coop(p, "", 2, nn.CoopVec(mi.Float(0, 1), mi.Float(1, 2), mi.Float(2, 3))))
    2
    """
    names = [f"{prefix}{i}.{kind}" for i in range(n_layers) for kind in ("weights", "bias")]
    return coop_apply(pack_layers([params[n] for n in names], half), n_layers, x, half)


def coop_apply(views, n_layers: int, x, half: bool = False):
    """The layers of :func:`dense_apply_coop` on weights already packed (:func:`pack_layers`: weights and
    biases alternating), so that a symbolic loop can call it: packing is a side effect that a loop's
    derivative cannot evaluate, so it is done once, outside."""
    if half:
        x = nn.cast(x, dr.float16_array_t(type(next(iter(x)))))
    for i in range(n_layers):
        x = nn.matvec(views[2 * i], x, views[2 * i + 1], transpose=True)
        if i + 1 < n_layers:
            x = dr.maximum(x, 0.0)
    Float = dr.float32_array_t(type(next(iter(x))))
    return [Float(v) for v in x]


def dense_init(sizes, TensorXf, rng, prefix: str = "") -> dict:
    """Parameters of layers ``sizes[0] -> sizes[1] -> ...`` as a plain dict of tensors.

    Keys ``{prefix}{l}.weights`` ((C_in, C_out), uniform Xavier from ``rng``) and
    ``{prefix}{l}.bias`` ((C_out,), zeros): a mapping ``drjit.opt`` optimisers take as is.

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> sorted(dense_init([3, 8, 2], mi.TensorXf, dr.rng(seed=0), prefix="mlp."))
    ['mlp.0.bias', 'mlp.0.weights', 'mlp.1.bias', 'mlp.1.weights']
    """
    sizes = tuple(int(s) for s in sizes)
    if len(sizes) < 2:
        raise ValueError(f"dense_init: needs at least input and output sizes, got {sizes}")
    Float32 = dr.float32_array_t(dr.leaf_t(TensorXf))
    params = {}
    for i, (c_in, c_out) in enumerate(zip(sizes[:-1], sizes[1:])):
        k = 1.0 / c_out**0.5
        w = rng.random(Float32, c_in * c_out)
        params[f"{prefix}{i}.weights"] = TensorXf(dr.fma(w, 2.0, -1.0) * k, shape=(c_in, c_out))
        params[f"{prefix}{i}.bias"] = dr.zeros(TensorXf, (c_out,))
    return params


def dense_apply(params, prefix: str, n_layers: int, x, activation=None, slices: int | None = None):
    """``h <- act(h W_l + b_l)`` for ``l < n_layers``, the last layer without activation.

    ``params``: a mapping as :func:`dense_init` makes; ``x``: (M, C_in) tensor -> (M, C_out);
    ``activation`` defaults to ReLU; ``slices``: the split-k batches of each product (:func:`matmul_rows`).

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> p = dense_init([3, 8, 2], mi.TensorXf, dr.rng(seed=0))
    >>> dense_apply(p, "", 2, dr.zeros(mi.TensorXf, (5, 3))).shape
    (5, 2)
    """
    act = activation or (lambda h: dr.maximum(h, 0.0))
    for i in range(n_layers):
        w, b = params[f"{prefix}{i}.weights"], params[f"{prefix}{i}.bias"]
        x = matmul_rows(x, w, slices=slices) + dr.reshape(type(b), b, (1, b.shape[0]))
        if i + 1 < n_layers:
            x = act(x)
    return x


#: The most rows of ``X`` one CUDA tensor product ``X W`` takes: Dr.Jit 1.5 (drjit-core's batched_gemm) lays
#: a tile of 8 to 64 rows on each step of the launch grid's y axis, at most 65535 of them, and a layer of odd
#: width (3 colours, 31 inputs) rules out all but 8-row tiles. Past it the product raises, which ``@`` turns
#: into "unsupported operand type(s)": ngp's 8192-ray batches (over 2^19 samples) failed so on an H200.
CUDA_GEMM_ROWS = 65535 * 8

#: Point batches of a split-k product on CUDA (:func:`matmul_rows`). drjit-core's GEMM launches
#: ceil(C_in / 8) x ceil(C_out / 8) blocks per product, so the weight gradient ``X^T dY`` of a 64-wide layer
#: (a (C_in, C_out) output contracted over every point) ran on 64 blocks that each walked all the points: tensor
#: mode stayed at 7.7 M points/s on an H200 whatever the batch. In 64 batches against 64 gathered copies of
#: the weights (one batched launch of 64 times the blocks, the copies' gradients summed by the gather's
#: adjoint) the same network trained at 57.4 M points/s at 2^20 points (benchmarks/throughput_mlp.py, the
#: second GPU run). On LLVM one product is faster (0.59 against 0.50 M points/s at 2^12 on 2 cores).
CUDA_SPLIT_K = 64


def gemm_row_cap(x) -> int:
    """The most rows one tensor product on ``x``'s backend takes: :data:`CUDA_GEMM_ROWS` on CUDA, 0 (no cap) on LLVM.

    >>> import drjit as dr
    >>> gemm_row_cap(dr.zeros(dr.llvm.ad.TensorXf, (2, 2)))
    0
    """
    return CUDA_GEMM_ROWS if dr.backend_v(x) == dr.JitBackend.CUDA else 0


def gemm_split_k(x) -> int:
    """The split-k batches :func:`matmul_rows` uses by default on ``x``'s backend: :data:`CUDA_SPLIT_K` on CUDA, 0
    (one product) on LLVM.

    >>> import drjit as dr
    >>> gemm_split_k(dr.zeros(dr.llvm.ad.TensorXf, (2, 2)))
    0
    """
    return CUDA_SPLIT_K if dr.backend_v(x) == dr.JitBackend.CUDA else 0


def matmul_rows(x, w, max_rows: int | None = None, slices: int | None = None):
    """``X W`` for a point-major (M, C_in) tensor ``x`` and (C_in, C_out) ``w``.

    Split-k (``slices`` S > 1, default :func:`gemm_split_k`): the first ``K = S floor(M / S)`` rows as S batches of
    K / S rows against S gathered copies of ``W``, ``(S, K/S, C_in) x (S, C_in, C_out)``, so that the weight
    gradient is S products over K / S points each in one launch (their sum is the gather's adjoint); the
    remaining ``M - K`` rows in one product. Each row's dot products are the same as in the whole product, and
    so are the gradients up to the order of their sums. Otherwise ``dr.matmul`` in slices of at most
    ``max_rows`` rows (default :func:`gemm_row_cap`; 0: one product). A batch of split-k keeps under the cap
    too (S grows in multiples of ``slices`` if K / S would pass it).

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> x, w = mi.TensorXf(list(range(10)), shape=(5, 2)), mi.TensorXf([1.0, 0, 0, 1], shape=(2, 2))
    >>> y = matmul_rows(x, w, max_rows=2)  # three slices: rows 0-1, 2-3, 4
    >>> y.shape, bool(dr.all(y.array == x.array))
    ((5, 2), True)
    >>> y = matmul_rows(x, w, slices=2)  # rows 0-1 and 2-3 as two batches, row 4 alone
    >>> y.shape, bool(dr.all(y.array == x.array))
    ((5, 2), True)
    """
    if max_rows is None:
        max_rows = gemm_row_cap(x)
    if slices is None:
        slices = gemm_split_k(x)
    m = x.shape[0]
    if slices > 1 and m >= slices:
        if max_rows:
            slices *= -(-m // (slices * max_rows))  # batches of at most max_rows rows
        return _matmul_split_k(x, w, slices, max_rows)
    if not max_rows or m <= max_rows:
        return dr.matmul(x, w)
    return dr.concat([dr.matmul(x[a:min(a + max_rows, m)], w) for a in range(0, m, max_rows)], axis=0)


def _matmul_split_k(x, w, slices: int, max_rows: int):
    """:func:`matmul_rows`' split-k product (``M >= slices``)."""
    T = type(x)
    (m, c_in), c_out = x.shape, w.shape[1]
    per = m // slices
    k = per * slices
    idx = dr.arange(dr.uint32_array_t(type(w.array)), slices * c_in * c_out) % (c_in * c_out)
    copies = T(dr.gather(type(w.array), w.array, idx), shape=(slices, c_in, c_out))
    head = x if k == m else x[:k]
    y = dr.reshape(T, dr.matmul(dr.reshape(T, head, (slices, per, c_in)), copies), (k, c_out))
    if k == m:
        return y
    return dr.concat([y, matmul_rows(x[k:], w, max_rows=max_rows, slices=0)], axis=0)


def rows_tensor(TensorXf, rows, width: int):
    """A point-major (width, C) tensor from C Float arrays of width ``width`` (a list or ArrayXf).

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> rows_tensor(mi.TensorXf, [mi.Float(1, 2), mi.Float(3, 4)], 2)
    [[1, 3],
     [2, 4]]
    """
    Float = dr.leaf_t(TensorXf)
    ArrayXf = sys.modules[Float.__module__].ArrayXf
    arr = rows if isinstance(rows, ArrayXf) else ArrayXf(*rows)
    return TensorXf(dr.ravel(arr, order="F"), shape=(width, len(arr)))


def column(t, j: int):
    """Column ``j`` of an (M, C) tensor as a Float array of width M."""
    return t[:, j].array

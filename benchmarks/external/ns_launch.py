"""Run nerfstudio's own ``ns-train`` / ``ns-render`` entry points with one thing replaced: the LPIPS metric.

nerfacto builds ``torchmetrics``' LPIPS when the model is constructed (``NerfactoModel.populate_modules``),
and that downloads torchvision's pretrained AlexNet weights at run time. A machine that reaches only
package registries cannot fetch them, so every ``ns-train nerfacto`` and ``ns-render`` (which builds
the model again) stops there with ``URLError``. LPIPS is an evaluation metric only (nerfacto's loss
never uses it), so this launcher replaces it by a module that returns NaN, and then runs nerfstudio's
unchanged entry point. Training and rendering are nerfstudio's own; nerfstudio's logged LPIPS is NaN.
It also lets ``ns-render`` load the checkpoint ``ns-train`` wrote: nerfstudio 1.1.5 stores numpy
scalars in it, which torch >= 2.6 refuses to load by default (``weights_only=True``).
mitsnerf scores the renders itself (``mitsnerf score``).

Run with nerfstudio's interpreter (``run_nerfacto.sh`` does)::

    VENV/bin/python benchmarks/external/ns_launch.py train nerfacto ...     # = ns-train nerfacto ...
    VENV/bin/python benchmarks/external/ns_launch.py render dataset ...     # = ns-render dataset ...
"""

from __future__ import annotations

import os
import sys

import torch
import torchmetrics.image.lpip


class NoLPIPS(torch.nn.Module):
    """Stands in for ``LearnedPerceptualImagePatchSimilarity``: no weights, and NaN for any pair of images."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__()

    def forward(self, preds: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        return torch.tensor(float("nan"), device=preds.device)


def main() -> None:
    if len(sys.argv) < 2 or sys.argv[1] not in ("train", "render"):
        sys.exit("usage: ns_launch.py train|render ARGS... (the arguments of ns-train / ns-render)")
    torchmetrics.image.lpip.LearnedPerceptualImagePatchSimilarity = NoLPIPS
    # nerfstudio 1.1.5 saves numpy scalars in its checkpoints, which torch >= 2.6's default
    # torch.load(weights_only=True) refuses; the checkpoint is the one ns-train just wrote.
    os.environ.setdefault("TORCH_FORCE_NO_WEIGHTS_ONLY_LOAD", "1")
    command = sys.argv.pop(1)
    sys.argv[0] = f"ns-{command}"
    if command == "train":
        from nerfstudio.scripts.train import entrypoint
    else:
        from nerfstudio.scripts.render import entrypoint
    entrypoint()


if __name__ == "__main__":
    main()

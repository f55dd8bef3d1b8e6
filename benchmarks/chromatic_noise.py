#!/usr/bin/env python3
"""The ground truth of a chromatic medium: per-channel noise and seconds of each estimator, side by side.

A chromatic medium (a 3-channel ``sigma_t``) rendered by Mitsuba's rgb ``volpath`` follows one colour channel
per camera path and weights the other two by ratios of their extinctions, and ``medium/``'s alpha estimates no
channel's ``1 - T`` (``benchmarks/chromatic_alpha.py``), so the one-pass composition cannot use the zero-mean
alpha term that keeps a grey medium's image as little noisy as a direct render. Each estimator below renders the
same views twice with independent seeds (those of ``test`` and ``test_ref``), and the script prints per colour
channel the variance of one image's pixel, ``mean over medium pixels of (a - b)^2 / 2``, the seconds of one
image (rendering plus the exact transmittance where the estimator uses it), and the figure of merit
``variance x seconds`` (the lower the better: the seconds a pixel needs to reach a given noise), each also as a
ratio to the direct render's; and the mean radiance over medium pixels against the direct render's, as a z, for
bias.

- ``direct``: ``volpath`` on the full scene (no ``medium/`` from it: that would be a second pass);
- ``direct_mis``: ``volpathmis`` (Mitsuba's spectral-MIS volumetric path tracer) on the full scene;
- ``composed``: the medium alone (``volpath``, ``hide_emitters``) plus the exact ``mean(T_k L_env,k)`` per channel,
  without an alpha term (dataset format 6's chromatic images);
- ``composed_mis``: the same with ``volpathmis``;
- ``per_channel``: three renders of the medium alone, channel ``k``'s with the grey ``sigma_t[..., k]``, each
  composed by the grey rule ``M + mean(T L) - mean(L) (alpha - (1 - mean T))`` and channel ``k`` kept
  (``mitsnerf.scene.render.render_channels`` and ``compose``: what ``mitsnerf generate`` does for a chromatic
  medium since dataset format 7). Radiative transfer in RGB does not couple the channels, so channel ``k`` of
  the grey medium is channel ``k`` of the chromatic one;
- ``direct+medium`` (derived, not rendered): ``direct``'s image with ``medium/`` from a second pass, the seconds
  of ``direct`` and ``composed`` together: what a direct render costs a dataset that has ``medium/``.

The medium-alone estimators' alpha is also tested against ``1 - T`` averaged over the channels (a z over every
pixel of both renders; ``per_channel``'s alpha is the mean of its three renders').

Timings interleave the estimators (test seeds in one order, test_ref seeds in the reverse) on one loaded scene
per medium, after a warm-up that compiles every estimator's kernels (a dataset renders many views per kernel);
the exact transmittance is timed on its second call. On a shared machine compare them as the ratios of one run.

    .venv/bin/python benchmarks/chromatic_noise.py --size 32 --views 3 --spp 256 smoke

One JSON line per estimator, then a table. Figures: docs/notes/chromatic.md, "The smoke's noise: one grey render
per channel".
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import mitsnerf  # noqa: F401  (libLLVM before drjit)
from mitsnerf import env

ESTIMATORS = ("direct", "direct_mis", "composed", "composed_mis", "per_channel")


class Bench:
    """One scene's views, its chromatic and per-channel grey Mitsuba scenes, and the exact transmittances."""

    def __init__(self, name: str, size: int, views: int, spp: int) -> None:
        import mitsuba as mi

        from mitsnerf.render.background import make_background
        from mitsnerf.scene.render import channel_scenes, footprint_for, write_volume
        from mitsnerf.scene.rigs import camera_rig
        from mitsnerf.scene.spec import load_scene
        from mitsnerf.scene.to_mitsuba import background_description, scene_box, scene_dict, volume_grids
        from mitsnerf.scoring.medium import medium_masks

        spec = load_scene(name).with_overrides({"cameras.width": size, "cameras.height": size,
                                                "render.spp_test": spp})
        sigma_t, albedo = volume_grids(spec)
        if sigma_t.ndim != 4:
            raise SystemExit(f"{name}: sigma_t is grey: nothing chromatic to measure")
        self.spec, self.sigma_t, self.box, self.spp = spec, sigma_t, scene_box(spec), spp
        tmp = Path(tempfile.mkdtemp(prefix="chromatic-noise-"))
        write_volume(tmp, spec, sigma_t, albedo, self.box)
        self.background = make_background(background_description(spec), tmp) if spec.environment else None
        self.cams = camera_rig(spec.cameras, "test")[:views]
        self.masks = medium_masks(sigma_t, self.box, self.cams)
        self.k = footprint_for(spp)
        self.scene = mi.load_dict(scene_dict(spec, sigma_t, albedo))
        self.grey = channel_scenes(spec, sigma_t, albedo)
        self.integrators = {(kind, hide): mi.load_dict({"type": kind, "max_depth": int(spec.render.max_depth),
                                                        "hide_emitters": hide})
                            for kind in ("volpath", "volpathmis") for hide in (False, True)}
        self.seen, self.transmittance_seconds = self._transmittances()

    def _transmittances(self):
        from mitsnerf.scene.transmittance import pixel_transmittance
        from mitsnerf.scoring.density import true_density

        seconds = []
        for _ in range(2):  # the second call timed: its kernels compiled, as for every split but a dataset's first
            start = time.perf_counter()
            seen = pixel_transmittance(true_density(self.sigma_t, self.box), self.sigma_t.shape[0], self.box,
                                       self.cams, footprint=self.k, background=self.background, channels=3)
            seconds.append(time.perf_counter() - start)
        return seen, seconds[-1]

    def warm(self, names: tuple[str, ...]) -> None:
        """Each estimator once at 1 spp on the first view, so that no timing includes compiling its kernels."""
        spp, cams = self.spp, self.cams
        self.spp, self.cams = 1, cams[:1]
        try:
            for n in names:
                self.estimate(n, "train")
        finally:
            self.spp, self.cams = spp, cams

    def _render(self, integrator, split: str) -> tuple[np.ndarray, float]:
        import mitsuba as mi

        from mitsnerf.scene.render import render_seed
        from mitsnerf.scene.to_mitsuba import load_sensor

        images, seconds = [], 0.0
        for i, cam in enumerate(self.cams):
            sensor = load_sensor(cam, self.spp)
            start = time.perf_counter()
            images.append(np.array(mi.render(self.scene, sensor=sensor, integrator=integrator, spp=self.spp,
                                             seed=render_seed(self.spec.render.seed, split, i)), dtype=np.float64))
            seconds += time.perf_counter() - start
        return np.stack(images), seconds

    def estimate(self, name: str, split: str) -> tuple[np.ndarray, np.ndarray | None, float]:
        """One image per view (V, H, W, 3) of estimator ``name`` with ``split``'s seeds, the alpha of its
        medium-alone render (None: a direct render has none), and its seconds (the transmittance's included)."""
        from mitsnerf.scene.render import compose, render_channels

        if name in ("direct", "direct_mis"):
            kind = "volpath" if name == "direct" else "volpathmis"
            img, s = self._render(self.integrators[(kind, False)], split)
            return img[..., :3], None, s
        if name in ("composed", "composed_mis"):
            kind = "volpath" if name == "composed" else "volpathmis"
            img, s = self._render(self.integrators[(kind, True)], split)
            through = self.seen.through if self.seen.through is not None else 0.0
            return img[..., :3] + through, img[..., 3], s + self.transmittance_seconds
        medium, alphas, timing = render_channels(self.grey, self.spec, split, self.cams, False)
        images = compose(medium, self.seen, self.background is not None, alphas)
        return (np.stack(images)[..., :3].astype(np.float64), np.stack(medium)[..., 3].astype(np.float64),
                timing["seconds"] + self.transmittance_seconds)

    def alpha_z(self, name: str, alphas: list[np.ndarray]) -> float:
        """The z of the mean alpha of ``alphas`` (independent renders) against ``1 - T`` averaged over the
        channels, with the binomial variance of the estimator's alpha (per channel: the mean of three)."""
        from mitsnerf.scoring.agreement import alpha_moments

        assert self.seen.t_rgb is not None
        per_pixel = self.seen.t_rgb if name == "per_channel" else self.seen.t
        p, var, _ = alpha_moments(per_pixel, float(self.spp))
        mean = np.mean([a.mean() for a in alphas])
        return float((mean - p.mean()) / (np.sqrt(var.sum() / len(alphas)) / var.size))


def measure(bench: Bench, names: tuple[str, ...]) -> dict[str, dict]:
    """Each estimator twice (``test`` seeds in order, ``test_ref`` seeds reversed): per-channel figures."""
    from mitsnerf.scoring.images import noise_floor

    bench.warm(names)
    images: dict[str, dict] = {n: {} for n in names}
    alphas: dict[str, list] = {n: [] for n in names}
    seconds: dict[str, float] = dict.fromkeys(names, 0.0)
    for split, order in (("test", names), ("test_ref", names[::-1])):
        for n in order:
            images[n][split], alpha, s = bench.estimate(n, split)
            seconds[n] += s
            alphas[n] += [] if alpha is None else [alpha]
    m = bench.masks
    out = {}
    for n in names:
        a, b = images[n]["test"], images[n]["test_ref"]
        var = 0.5 * (a - b)[m] ** 2  # (pixels, 3): one image's variance per pixel, unbiased
        out[n] = {"variance": var.mean(0), "seconds": seconds[n] / 2, "mean": 0.5 * (a + b)[m].mean(0),
                  "se_mean": np.sqrt(var.sum(0) / 2) / len(var),
                  "floor_medium_db": noise_floor(a.astype(np.float32), b.astype(np.float32), m)["psnr_medium"],
                  "alpha_z": bench.alpha_z(n, alphas[n]) if alphas[n] else None}
    return out


def with_second_pass(figures: dict[str, dict]) -> dict[str, dict]:
    """``figures`` and, derived, ``direct+medium``: a direct render's image with ``medium/`` from a second pass
    of the medium alone (the two-pass ground truth): the direct render's variance, the seconds of ``direct``
    and ``composed`` (the medium alone and its exact transmittance) together."""
    if "composed" not in figures:
        return figures
    d, c = figures["direct"], figures["composed"]
    return {**figures, "direct+medium": {**d, "seconds": d["seconds"] + c["seconds"], "alpha_z": c["alpha_z"]}}


def report(bench: Bench, figures: dict[str, dict]) -> list[dict]:
    figures = with_second_pass(figures)
    base = figures["direct"]
    rows = []
    for n, f in figures.items():
        z = (f["mean"] - base["mean"]) / np.sqrt(f["se_mean"] ** 2 + base["se_mean"] ** 2)
        merit = f["variance"] * f["seconds"]
        rows.append({"estimator": n, "scene": bench.spec.name, "size": bench.cams[0].width, "views": len(bench.cams),
                     "spp": bench.spp, "medium_pixels": int(bench.masks.sum()), "seconds_per_image": f["seconds"],
                     "variance_rgb": f["variance"].tolist(),
                     "variance_ratio_to_direct_rgb": (f["variance"] / base["variance"]).tolist(),
                     "seconds_ratio_to_direct": f["seconds"] / base["seconds"],
                     "variance_x_seconds_ratio_to_direct_rgb": (merit / (base["variance"] * base["seconds"])).tolist(),
                     "mean_rgb": f["mean"].tolist(), "bias_z_vs_direct_rgb": [0.0] * 3 if n == "direct" else z.tolist(),
                     "noise_floor_medium_db": f["floor_medium_db"],
                     "alpha_z_vs_one_minus_mean_T": f["alpha_z"]})
    return rows


def _table(rows: list[dict]) -> str:
    def rgb(v, fmt="{:.2f}"):
        return " / ".join(fmt.format(x) for x in v)

    lines = ["| estimator | variance / direct's, R / G / B | seconds / direct's | variance x seconds / direct's, "
             "R / G / B | bias z vs direct, R / G / B | noise floor dB (medium) | alpha's z vs 1 - mean T |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['estimator']} | {rgb(r['variance_ratio_to_direct_rgb'])} | "
                     f"{r['seconds_ratio_to_direct']:.2f} | {rgb(r['variance_x_seconds_ratio_to_direct_rgb'])} | "
                     f"{rgb(r['bias_z_vs_direct_rgb'], '{:+.1f}')} | {r['noise_floor_medium_db']:.2f} | "
                     + ("-" if r["alpha_z_vs_one_minus_mean_T"] is None else f"{r['alpha_z_vs_one_minus_mean_T']:+.1f}")
                     + " |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="+")
    ap.add_argument("--size", type=int, default=32, help="width and height of the views")
    ap.add_argument("--views", type=int, default=3, help="test views of the scene's rig")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--estimators", nargs="+", choices=ESTIMATORS, default=list(ESTIMATORS))
    args = ap.parse_args()
    env.set_variant("llvm_ad_rgb")
    names = tuple(["direct"] + [n for n in args.estimators if n != "direct"])
    for name in args.scenes:
        bench = Bench(name, args.size, args.views, args.spp)
        rows = report(bench, measure(bench, names))
        for row in rows:
            print(json.dumps(row), flush=True)
        print(_table(rows), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Figures of a sweep (matplotlib, Agg canvas, PNG), one set per scene.

- ``psnr_time_<scene>.png``: held-out PSNR against training time (evaluation excluded), whole
  image and medium pixels, one colour per method, one line per seed, the noise floor dashed;
- ``per_view_<scene>.png``: test PSNR per view (mean over seeds) with the per-view noise floor;
- ``error_budget_<scene>.png``: each method's medium PSNR against the oracle and the reference agreement (the
  noise floor), its value and gap written right of the plot, clear of the lines;
- ``images_<scene>.png``: the report view: ground truth and its medium-pixel mask, each
  method's render (first seed) and its error map ``mean_c |render - truth|`` (linear,
  clipped) on a shared scale;
- ``density_<scene>.png``: central z, y and x slices of the true and learned density.

Images are shown sRGB-encoded; density slices with index ``[z, y, x]`` drawn with the
second index up.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from mitsnerf.math.color import linear_to_srgb


def _figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def _label(ax, xlabel: str, ylabel: str, title: str) -> None:
    """Axis labels, title, a light grid, and a legend when something is labelled."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)


def _save(fig, path: Path) -> Path:
    from mitsnerf.data.atomic import atomic_path

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return path


def _colours(methods: Sequence[str]) -> dict[str, tuple]:
    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    return {m: cmap(i % 10) for i, m in enumerate(methods)}


def _floor(records: Sequence[dict], key: str) -> float | None:
    for r in records:
        value = (r.get("metrics") or {}).get(key)
        if value is not None:
            return float(value)
    return None


def psnr_time(scene: str, records: Sequence[dict], methods: Sequence[str], path: Path) -> Path:
    fig = _figure(10, 4)
    colours = _colours(methods)
    for ax, key, title, floor_key in (
        (fig.add_subplot(1, 2, 1), "psnr", "whole image", "noise_floor_psnr"),
        (fig.add_subplot(1, 2, 2), "psnr_medium", "medium pixels", "noise_floor_psnr_medium"),
    ):
        ceiling = _floor(records, floor_key.replace("noise_floor_psnr", "oracle_psnr_test"))
        if ceiling is not None:
            ax.axhline(ceiling, color="tab:red", ls=":", lw=1.5, label="oracle (EA ceiling)")
        for method in methods:
            first = True
            for r in records:
                if r["method"] != method:
                    continue
                pts = [p for p in (r.get("curve") or {}).get("points", []) if p.get(key) is not None]
                if not pts:
                    continue
                ax.plot([p["seconds"] for p in pts], [p[key] for p in pts], "o-", ms=3, color=colours[method],
                        label=method if first else None, alpha=0.9)
                first = False
        floor = _floor(records, floor_key)
        if floor is not None:
            ax.axhline(floor, color="k", ls="--", lw=1, label="ref agreement (two GT renders)")
        _label(ax, "training time, s (evaluation excluded)", "held-out PSNR, dB (linear)", f"{scene}: {title}")
    fig.tight_layout()
    return _save(fig, path)


def per_view(scene: str, records: Sequence[dict], methods: Sequence[str], path: Path) -> Path:
    fig = _figure(7, 4)
    ax = fig.add_subplot(1, 1, 1)
    colours = _colours(methods)
    for method in methods:
        per = [r["metrics"].get("psnr_test_per_view") for r in records if r["method"] == method]
        per = [p for p in per if p]
        if not per:
            continue
        n = min(len(p) for p in per)
        values = np.array([[np.nan if v is None else v for v in p[:n]] for p in per], dtype=float)
        ax.plot(np.arange(n), np.nanmean(values, axis=0), "o-", color=colours[method], label=method)
    floor = next((r["metrics"].get("noise_floor_psnr_per_view") for r in records
                  if r["metrics"].get("noise_floor_psnr_per_view")), None)
    if floor:
        ax.plot(
            np.arange(len(floor)),
            [np.nan if v is None else v for v in floor],
            "k--",
            lw=1,
            label="ref agreement (two GT renders)",
        )
    ceiling = next(((r.get("oracle") or {}).get("psnr_test_per_view") for r in records
                    if (r.get("oracle") or {}).get("psnr_test_per_view")), None)
    if ceiling:
        ax.plot(np.arange(len(ceiling)), [np.nan if v is None else v for v in ceiling], ":", color="tab:red",
                lw=1.5, label="oracle (EA ceiling)")
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    _label(ax, "test view", "PSNR, dB (linear, whole image)", f"{scene}: test PSNR per view (mean over seeds)")
    fig.tight_layout()
    return _save(fig, path)


def _first_seed(records: Sequence[dict], methods: Sequence[str]) -> list[dict]:
    out = []
    for method in methods:
        mine = sorted((r for r in records if r["method"] == method), key=lambda r: r["seed"])
        if mine:
            out.append(mine[0])
    return out


def _srgb(img: np.ndarray) -> np.ndarray:
    return np.clip(linear_to_srgb(np.clip(img, 0.0, 1.0)), 0.0, 1.0)


def image_grid(scene: str, records: Sequence[dict], methods: Sequence[str], artefacts: Mapping[str, Mapping],
               path: Path) -> Path | None:
    shown = [r for r in _first_seed(records, methods) if "render" in artefacts.get(r["key"], {})]
    if not shown:
        return None
    ref = np.asarray(artefacts[shown[0]["key"]]["ref"])
    view = int(artefacts[shown[0]["key"]].get("view", 0))
    errors = [np.abs(np.clip(artefacts[r["key"]]["render"], 0, 1) - np.clip(ref, 0, 1)).mean(axis=-1) for r in shown]
    vmax = max(float(np.percentile(e, 99.5)) for e in errors) or 1e-6
    cols = len(shown) + 1
    fig = _figure(2.2 * cols + 0.6, 4.6)
    ax = fig.add_subplot(2, cols, 1)
    ax.imshow(_srgb(ref))
    ax.set_title("ground truth", fontsize=9)
    ax.axis("off")
    mask = artefacts[shown[0]["key"]].get("mask")
    if mask is not None:
        ax = fig.add_subplot(2, cols, cols + 1)
        ax.imshow(np.asarray(mask, dtype=float), cmap="gray", vmin=0.0, vmax=1.0)
        ax.set_title("medium pixels", fontsize=9)
        ax.axis("off")
    im = None
    for i, (r, err) in enumerate(zip(shown, errors)):
        per = r["metrics"].get("psnr_test_per_view") or []
        label = f"{r['method']}" + (f"\n{per[view]:.2f} dB" if view < len(per) and per[view] is not None else "")
        ax = fig.add_subplot(2, cols, i + 2)
        ax.imshow(_srgb(np.asarray(artefacts[r["key"]]["render"])))
        ax.set_title(label, fontsize=9)
        ax.axis("off")
        ax = fig.add_subplot(2, cols, cols + i + 2)
        im = ax.imshow(err, cmap="inferno", vmin=0.0, vmax=vmax)
        ax.set_title("|error|", fontsize=9)
        ax.axis("off")
    if im is not None:
        fig.colorbar(im, ax=fig.axes[-1], fraction=0.046, pad=0.04)
    fig.suptitle(f"{scene}: test view {view} (sRGB; error linear)", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def density_slices(scene: str, records: Sequence[dict], methods: Sequence[str], artefacts: Mapping[str, Mapping],
                   path: Path) -> Path | None:
    shown = _first_seed(records, methods)
    truth_src = next((artefacts[r["key"]] for r in shown if "true_z" in artefacts.get(r["key"], {})), None)
    if truth_src is None:
        return None
    axes_names = ("z", "y", "x")
    vmax = max(float(np.max(truth_src[f"true_{a}"])) for a in axes_names) or 1.0
    cols = len(shown) + 1
    fig = _figure(2.2 * cols + 0.8, 6.6)
    im = None
    for row, a in enumerate(axes_names):
        ax = fig.add_subplot(3, cols, row * cols + 1)
        im = ax.imshow(truth_src[f"true_{a}"], origin="lower", cmap="viridis", vmin=0.0, vmax=vmax)
        ax.set_title(f"true, {a} slice" if row == 0 else f"{a} slice", fontsize=9)
        ax.axis("off")
        for i, r in enumerate(shown):
            ax = fig.add_subplot(3, cols, row * cols + i + 2)
            data = artefacts.get(r["key"], {})
            if f"learned_{a}" in data:
                ax.imshow(data[f"learned_{a}"], origin="lower", cmap="viridis", vmin=0.0, vmax=vmax)
            else:
                ax.text(0.5, 0.5, "no queryable\ndensity", ha="center", va="center", fontsize=8, transform=ax.transAxes)
            if row == 0:
                ax.set_title(r["method"], fontsize=9)
            ax.axis("off")
    if im is not None:
        fig.colorbar(im, ax=fig.axes, fraction=0.02, pad=0.02, label="sigma_t")
    fig.suptitle(f"{scene}: density, central slices (shared scale)", fontsize=10)
    return _save(fig, path)


def error_budget(scene: str, records: Sequence[dict], methods: Sequence[str], path: Path) -> Path | None:
    """Each method's medium PSNR (mean over seeds) as a bar, the oracle (the emission-absorption ceiling) and
    the reference agreement (noise floor) as lines, each bar's value and gap to the oracle written right of
    the axes (clear of the lines, whatever they cross); None without medium scores."""
    from matplotlib.transforms import blended_transform_factory

    per_seed = {m: [r["metrics"].get("psnr_test_medium") for r in records if r["method"] == m] for m in methods}
    values = {m: float(np.mean([v for v in vs if v is not None])) for m, vs in per_seed.items()
              if any(v is not None for v in vs)}
    if not values:
        return None
    oracle = _floor(records, "oracle_psnr_test_medium")
    floor = _floor(records, "noise_floor_psnr_medium")
    fig = _figure(7.2, 1.9 + 0.45 * len(values))
    fig.set_layout_engine("constrained")  # room for the axis label and the notes right of the axes
    ax = fig.add_subplot(1, 1, 1)
    colours = _colours(methods)
    names = list(values)
    ax.barh(range(len(names)), [values[m] for m in names], color=[colours[m] for m in names])
    lines = [v for v in (oracle, floor) if v is not None]
    beside = blended_transform_factory(ax.transAxes, ax.transData)
    for i, m in enumerate(names):
        gap = f", {oracle - values[m]:.2f} below the oracle" if oracle is not None else ""
        ax.text(1.02, i, f"{values[m]:.2f} dB{gap}", va="center", fontsize=8, transform=beside)
    if oracle is not None:
        ax.axvline(oracle, color="tab:red", ls=":", lw=1.5, label=f"oracle (EA ceiling) {oracle:.2f}")
    if floor is not None:
        ax.axvline(floor, color="k", ls="--", lw=1, label=f"ref agreement (two GT renders) {floor:.2f}")
    ax.set_yticks(range(len(names)), names)
    ax.set_xlim(left=max(min([*values.values(), *lines]) - 3.0, 0.0), right=max([*values.values(), *lines]) + 1.0)
    _label(ax, "PSNR on medium pixels (dB)", "", f"{scene}: error budget")
    if lines:
        ax.get_legend().remove()
        fig.legend(fontsize=8, loc="outside lower center", ncols=2)
    return _save(fig, path)


def scene_figures(scene: str, records: Sequence[dict], methods: Sequence[str], artefacts: Mapping[str, Mapping],
                  out_dir: Path) -> list[tuple[str, Path]]:
    """Every figure of one scene: ``[(caption, path), ...]``."""
    out_dir = Path(out_dir)
    figures = [
        ("Held-out PSNR against training time", psnr_time(scene, records, methods, out_dir / f"psnr_time_{scene}.png")),
        ("Test PSNR per view", per_view(scene, records, methods, out_dir / f"per_view_{scene}.png")),
        (
            "Error budget: medium PSNR against the oracle and the noise floor",
            error_budget(scene, records, methods, out_dir / f"error_budget_{scene}.png"),
        ),
        (
            "Ground truth, renders and error maps",
            image_grid(scene, records, methods, artefacts, out_dir / f"images_{scene}.png"),
        ),
        (
            "Density: true and learned",
            density_slices(scene, records, methods, artefacts, out_dir / f"density_{scene}.png"),
        ),
    ]
    return [(caption, p) for caption, p in figures if p is not None]

"""``mitsnerf env``."""

from __future__ import annotations

import json


def cache_info() -> dict[str, object]:
    """Where datasets and oracles are cached (:func:`mitsnerf.outputs.data_cache`), what chose that place, and how
    much it holds: ``{"path", "chosen_by", "exists", "datasets", "files", "bytes", "size"}``."""
    from mitsnerf.outputs import data_cache, directory_size

    path, chosen_by = data_cache()
    size, files = directory_size(path)
    datasets = sum(1 for p in path.iterdir() if (p / "manifest.json").is_file()) if path.is_dir() else 0
    return {"path": str(path), "chosen_by": chosen_by, "exists": path.is_dir(), "datasets": datasets, "files": files,
            "bytes": size, "size": f"{size / 2**20:.1f} MiB"}


def run(args) -> int:
    from mitsnerf import env

    print(json.dumps({**env.provenance(), "data_cache": cache_info()}, indent=2))
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("env", help="print the environment: variant, versions, LLVM, commit, and the dataset cache "
                                   "(where, how big)")
    p.set_defaults(func=run)

"""``mitsnerf generate``."""

from __future__ import annotations

from pathlib import Path

from mitsnerf.cli.common import NO_PROGRESS_HELP, SCENES_HELP, parse_overrides, with_user_dirs


def _scene_overrides(args) -> dict:
    """``--nerf-synthetic`` (the box at [-1.5, 1.5]^3, cameras at radius 4), then the ``--set`` pairs over it."""
    from mitsnerf.scene.spec import nerf_synthetic_overrides

    return {**(nerf_synthetic_overrides() if args.nerf_synthetic else {}), **parse_overrides(args.set)}


@with_user_dirs
def run(args) -> int:
    from mitsnerf.errors import UsageError
    from mitsnerf.generate import generate_all, generate_dataset
    from mitsnerf.outputs import check_output_dir, data_cache
    from mitsnerf.scene.spec import open_scene

    if not args.all and not args.scene:
        raise UsageError("generate", "name a SCENE or pass --all")
    out = Path(args.out) if args.out else data_cache()[0]
    check_output_dir(out, "--out" if args.out else f"dataset cache (chosen by {data_cache()[1]}; --out moves it)")
    overrides = _scene_overrides(args)
    if args.all:
        for path in generate_all(out, overrides=overrides, force=args.force,
                                 verify_hashes=not args.no_verify, progress=not args.no_progress):
            print(path)
        return 0
    spec = open_scene(args.scene, overrides)
    print(generate_dataset(spec, out, force=args.force, verify_hashes=not args.no_verify,
                           progress=not args.no_progress))
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("generate", help="render a scene's ground-truth dataset with Mitsuba's volpath")
    p.add_argument("scene", nargs="?", help="a scene name (mitsnerf scenes lists them), the path of a spec (which may "
                                            "start from a scene: extends = \"cloud\"), or a grid file (.npy/.npz "
                                            "[z, y, x] or Mitsuba .vol): the cloud scene with that medium, at the "
                                            "grid's resolution (--set volume.sigma_t_scale=..., --set "
                                            "volume.params.array=NAME for an .npz of several arrays)")
    p.add_argument("--scenes", action="append", metavar="DIR", help=SCENES_HELP)
    p.add_argument("--out", metavar="DIR",
                   help="dataset root; the dataset goes to DIR/NAME-HASH, and its path is printed (default: the "
                        "cache `mitsnerf bench` uses: $MITSNERF_DATA, else $XDG_CACHE_HOME/mitsnerf, else "
                        "~/.cache/mitsnerf)")
    p.add_argument("--all", action="store_true", help="render every scene of the library and of --scenes")
    p.add_argument("--force", action="store_true", help="render again even if cached")
    p.add_argument("--no-verify", action="store_true",
                   help="on a cache hit, skip checking the files against the manifest's sha256 hashes")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a spec field, e.g. cameras.width=32")
    p.add_argument("--nerf-synthetic", action="store_true",
                   help="write the scene at the NeRF-synthetic scale: box [-1.5, 1.5]^3 (world.scale=3, sigma_t / 3), "
                        "cameras at radius 4, where those readers' near/far 2..6 work; --set wins over it")
    p.add_argument("--no-progress", action="store_true", help=NO_PROGRESS_HELP)
    p.set_defaults(func=run)

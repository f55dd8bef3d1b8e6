"""A run saved before a setting existed is read as it trained, not with today's default: scatter's ``carve`` and
``init_depth`` (true and 5 today) read as the run trained (false, 0) when loaded, rendered and resumed; a setting
whose old behaviour no value reproduces (nerf's ``use_direction``) refuses the run in one line."""

from __future__ import annotations

import dataclasses
import json
import shutil

from mitsnerf.cli import main
from mitsnerf.runs.fit import load_run
from mitsnerf.train.checkpoint import CHECKPOINT_FILE, load_checkpoint, save_checkpoint

SCATTER = ("--method", "scatter", "--set", "hash.n_levels=2", "--set", "hash.log2_hashmap_size=10",
           "--set", "hash.base_resolution=8", "--set", "hash.max_resolution=16", "--set", "hash.hidden=8",
           "--set", "hash.color_hidden=8", "--set", "n_samples=16", "--set", "field.shadow_resolution=4",
           "--set", "field.shadow_samples=4", "--set", "field.shadow_density_resolution=4",
           "--set", "occupancy.resolution=8", "--batch-rays", "32")


def _forget(run, *keys: str) -> None:
    """Remove dotted ``keys`` of ``method_config`` from the run's config.json and checkpoint, as a run saved before
    those settings existed holds them."""
    def drop(config: dict) -> dict:
        config = json.loads(json.dumps(config))
        for key in keys:
            *parents, last = key.split(".")
            table = config["method_config"]
            for part in parents:
                table = table[part]
            del table[last]
        return config

    path = run / "config.json"
    path.write_text(json.dumps(drop(json.loads(path.read_text()))))
    ckpt = load_checkpoint(run / CHECKPOINT_FILE)
    save_checkpoint(run / CHECKPOINT_FILE, dataclasses.replace(ckpt, config=drop(ckpt.config)))


def test_a_scatter_run_saved_before_carve_loads_renders_and_resumes_as_it_trained(world, tmp_path, capsys):
    run = tmp_path / "old"
    assert main(["train", str(world.dataset), "--out", str(run), "--steps", "2", "--no-progress", *SCATTER,
                 "--set", "carve=false", "--set", "init_depth=0"]) == 0
    _forget(run, "carve", "init_depth")
    (run / CHECKPOINT_FILE).rename(tmp_path / CHECKPOINT_FILE)  # load_run reads config.json + params.npz alone
    model, _, _ = load_run(run)
    assert (model.config.carve, model.config.init_depth) == (False, 0.0)
    (tmp_path / CHECKPOINT_FILE).rename(run / CHECKPOINT_FILE)
    model, _, _ = load_run(run)  # from the checkpoint's config
    assert (model.config.carve, model.config.init_depth) == (False, 0.0)
    assert main(["render", str(run), "--out", str(tmp_path / "renders"), "--no-progress"]) == 0
    assert main(["train", "--resume", "--out", str(run), "--steps", "3", "--no-progress"]) == 0, capsys.readouterr()
    saved = json.loads((run / "config.json").read_text())["method_config"]
    assert (saved["carve"], saved["init_depth"]) == (False, 0.0)  # recorded from now on


def test_a_run_whose_old_behaviour_no_setting_reproduces_is_refused_in_one_line(world, tmp_path, capsys):
    run = tmp_path / "old"
    shutil.copytree(world.run, run)
    _forget(run, "network.use_direction")
    capsys.readouterr()
    assert main(["render", str(run), "--out", str(tmp_path / "renders"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{run / CHECKPOINT_FILE}: method_config.network.use_direction: not recorded: " \
        "saved before 0.1.0+7225556 added this setting" in err, err
    assert not (tmp_path / "renders").exists()

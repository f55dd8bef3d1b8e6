"""The command line is built from the registries and the configs' declarations, so --help cannot drift."""

from __future__ import annotations

import pytest

from mitsnerf.cli import main
from mitsnerf.config import option_spec
from mitsnerf.train.evaluate import EvalConfig
from mitsnerf.methods import methods
from mitsnerf.train import TrainConfig


@pytest.fixture(autouse=True)
def _wide(monkeypatch):
    monkeypatch.setenv("COLUMNS", "10000")  # argparse wraps at $COLUMNS; a hyphenated name must stay whole


def _help(capsys, *argv: str) -> str:
    with pytest.raises(SystemExit):
        main([*argv, "--help"])
    return " ".join(capsys.readouterr().out.split())


def test_train_help_lists_every_registered_method_and_its_learning_rate(capsys):
    text = _help(capsys, "train")
    for name, entry in methods().items():
        assert f"{name}: {entry.description}" in text
        assert f"{name} {option_spec(entry.config_type, 'lr').default:g}" in text


@pytest.mark.parametrize(("cls", "field", "flag"), [(TrainConfig, "batch_rays", "--batch-rays"),
                                                    (TrainConfig, "steps", "--steps"),
                                                    (TrainConfig, "pixel_jitter", "--no-pixel-jitter"),
                                                    (EvalConfig, "footprint", "--footprint")])
def test_train_options_say_what_their_config_field_declares(capsys, cls, field, flag):
    text = _help(capsys, "train")
    spec = option_spec(cls, field)
    assert flag in text
    if spec.kind is not bool:
        assert f"{spec.what}; default {spec.default}" in text


def test_a_bad_option_value_is_blamed_on_the_option(world, tmp_path, capsys):
    assert main(["train", str(world.dataset), "--out", str(tmp_path / "r"), "--batch-rays", "0"]) == 2
    assert "mitsnerf: error: --batch-rays: must be an integer in [1, 4194304], got 0" in capsys.readouterr().err


def test_resume_refuses_a_setting_the_checkpoint_fixes(world, tmp_path, capsys):
    assert main(["train", "--resume", "--out", str(world.run), "--no-pixel-jitter"]) == 2
    assert "--no-pixel-jitter come from the checkpoint" in capsys.readouterr().err


def test_a_reader_that_goes_away_stops_the_command_quietly():
    """`mitsnerf scenes | head -1`: the pipe closes before the command writes; it stops with SIGPIPE's status and
    no traceback (it used to end in BrokenPipeError's)."""
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "mitsnerf", "scenes"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    proc.stdout.close()  # long before the child has imported anything, let alone written
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 141 and b"Traceback" not in err and b"BrokenPipe" not in err, err.decode()


@pytest.mark.parametrize(("argv", "line"), [
    (["train", "d", "--out", "r", "--stpes", "10"],
     "mitsnerf: error: mitsnerf train: unrecognized arguments: --stpes 10 (did you mean --steps?) "
     "(see mitsnerf train --help)\n"),
    (["train", "d", "--out", "r", "--bogus"],
     "mitsnerf: error: mitsnerf train: unrecognized arguments: --bogus (see mitsnerf train --help)\n"),
    (["trian"], "(did you mean train?) (see mitsnerf --help)\n"),
])
def test_a_mistyped_option_is_named_by_its_command_once_with_the_closest_name(capsys, argv, line):
    """``train ... --stpes 10`` printed 'mitsnerf: error: mitsnerf: unrecognized arguments' (the prefix twice, the
    command not named) and no "did you mean"."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.endswith(line) and err.count("\n") == 1, err
    assert "error: mitsnerf: " not in err, err

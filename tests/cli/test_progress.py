"""Progress bars: on a terminal unless ``--no-progress``; never in a log (stderr not a terminal).

Each long command that draws a tqdm bar (train, generate, render) is run with stderr a stand-in
terminal and with stderr captured as a log file would be, with and without ``--no-progress``.
"""

from __future__ import annotations

import io
import shutil
import sys

import pytest

from mitsnerf.cli import main


class _Terminal(io.StringIO):
    """stderr as a terminal: what tqdm asks before it draws."""

    def isatty(self) -> bool:
        return True


def _stderr_of(argv: list[str], terminal: bool, monkeypatch, capsys) -> str:
    """What ``mitsnerf ARGV`` writes to stderr, a terminal or (``terminal=False``) captured as a file."""
    if not terminal:
        assert main(argv) == 0
        return capsys.readouterr().err
    screen = _Terminal()
    monkeypatch.setattr(sys, "stderr", screen)
    assert main(argv) == 0
    return screen.getvalue()


COMMANDS = {
    "train": (lambda world, out: ["train", str(world.dataset), "--out", str(out), "--steps", "2", *world.nerf],
              "train nerf"),
    "generate": (lambda world, out: ["generate", str(world.spec), "--out", str(out)], "tiny train"),
    "render": (lambda world, out: ["render", str(out), "--orbit", "2", "--out", str(out / "orbit")], "render"),
}


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("terminal, flag, shown", [(True, False, True), (True, True, False), (False, False, False)],
                         ids=["terminal", "terminal-no-progress", "log"])
def test_a_bar_only_on_a_terminal_and_never_with_no_progress(world, tmp_path, monkeypatch, capsys, command,
                                                             terminal, flag, shown):
    make_argv, bar = COMMANDS[command]
    out = tmp_path / "out"
    if command == "render":
        shutil.copytree(world.run, out)
    argv = make_argv(world, out) + (["--no-progress"] if flag else [])
    err = _stderr_of(argv, terminal, monkeypatch, capsys)
    assert (bar in err) == shown, err
    assert ("it/s" in err or "step/s" in err or "view/s" in err) == shown, err

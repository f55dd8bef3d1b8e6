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
    assert (f"{bar}: " in err) == shown, err  # tqdm's "DESC: 50%|..."; a progress line is no bar
    assert ("it/s" in err or "step/s" in err or "view/s" in err) == shown, err


LINES = {
    "train": (lambda world, out: ["train", str(world.dataset), "--out", str(out), "--steps", "2", *world.nerf],
              ["[train] nerf: steps 0 to 2 ...", "[train] nerf: step 2 of 2, loss ",
               "[train] nerf: 2 steps in ", "rendering the 2 test views to score them ..."]),
    "generate": (lambda world, out: ["generate", str(world.spec), "--out", str(out)],
                 ["[tiny] train: rendering 3 views of 8x8 at 4 spp ...", "[tiny] train: 3 views in ",
                  "[tiny] test: rendering 2 views of 8x8 at 8 spp ..."]),
    "render": (lambda world, out: ["render", str(world.run), "--orbit", "2", "--out", str(out)],
               ["[render] 2 views of 8x8 at footprint 3 from ", "[render] 2 views in "]),
    "export": (lambda world, out: ["export", str(world.run), "--resolution", "4", "--out", str(out)],
               ["[export] nerf's density and colour (averaged over 16 directions) at the 64 voxel centres of a 4^3 "
                "grid", "[export] written in "]),
}


@pytest.mark.parametrize("command", LINES)
def test_a_long_command_says_what_it_is_doing_in_a_log_unless_told_not_to(world, tmp_path, capsys, command):
    """stderr not a terminal (a log file): no bar, but lines saying what the command is doing, as bench prints them
    (generate used to run for 18 minutes printing one line at the end); --no-progress: none."""
    make_argv, lines = LINES[command]
    assert main(make_argv(world, tmp_path / "out")) == 0
    err = capsys.readouterr().err
    assert all(line in err for line in lines), err
    assert main(make_argv(world, tmp_path / "quiet") + ["--no-progress"]) == 0
    err = capsys.readouterr().err
    assert lines[0].split("]")[0] + "]" not in err, err  # [train], [tiny], [render], [export]

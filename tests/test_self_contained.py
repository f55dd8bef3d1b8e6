"""The project speaks of itself alone: no file of the repository cites a document outside it."""

from __future__ import annotations

import re

#: What citing outside material looks like (written in pieces, so this file does not match itself).
OUTSIDE = re.compile("|".join(["DEVELOPERS" + r"\.md", r"\.\./" + "shared", "/work/" + "shared"]))


def test_no_file_cites_a_document_outside_the_repository(checkout_files):
    root, names = checkout_files
    hits = []
    for name in names:
        path = root / name
        if path.is_symlink() or not path.is_file():
            continue
        text = path.read_bytes().decode("utf-8", errors="replace")
        hits += [f"{name}:{text.count(chr(10), 0, m.start()) + 1}: {m.group()}" for m in OUTSIDE.finditer(text)]
    assert not hits, "\n".join(hits)


def test_the_pattern_sees_each_kind_of_citation():
    for cited in ["see " + "DEVELOPERS" + ".md", "../" + "shared/peers/x.py", "/work/" + "shared/notes"]:
        assert OUTSIDE.search(cited), cited
    assert not OUTSIDE.search("shared by every method; docs/conventions.md")

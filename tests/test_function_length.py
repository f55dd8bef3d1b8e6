"""Functions short enough to read at once: no function body in ``mitsnerf/`` over ``LIMIT`` lines.

The body is counted from its first statement after the docstring to its last line (comments and
blank lines inside count: they are read too). An exception is listed below with its reason.
"""

from __future__ import annotations

import ast
from pathlib import Path

import mitsnerf

LIMIT = 60
ROOT = Path(mitsnerf.__file__).parent

#: "path:function" -> why it stays longer (each one must still be over the limit).
EXCEPTIONS: dict[str, str] = {}


def body_lines(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Lines from the first statement after the docstring to the function's end.

    >>> body_lines(ast.parse('def f():\\n    \\"\\"\\"Doc.\\"\\"\\"\\n    x = 1\\n\\n    return x\\n').body[0])
    3
    """
    body = node.body
    if isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str):
        body = body[1:]
    return node.end_lineno - body[0].lineno + 1 if body else 0


def long_functions(limit: int = LIMIT) -> dict[str, int]:
    """``path:qualified name`` -> body lines, of every function in ``mitsnerf/`` over ``limit``."""
    out = {}
    for path in sorted(ROOT.rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        stack = [(node, "") for node in tree.body]
        while stack:
            node, prefix = stack.pop()
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = prefix + node.name
                if not isinstance(node, ast.ClassDef) and body_lines(node) > limit:
                    out[f"{path.relative_to(ROOT).as_posix()}:{name}"] = body_lines(node)
                stack += [(child, name + ".") for child in node.body]
    return out


def test_no_function_is_longer_than_the_limit():
    over = {name: n for name, n in long_functions().items() if name not in EXCEPTIONS}
    assert not over, "split these (or list a reason in EXCEPTIONS): " + ", ".join(f"{k} ({n} lines)" for k, n in over.items())


def test_every_exception_is_still_needed():
    stale = sorted(set(EXCEPTIONS) - set(long_functions()))
    assert not stale, f"no longer over {LIMIT} lines, remove from EXCEPTIONS: {stale}"


def test_the_scan_counts_the_body_without_the_docstring():
    lines = ["def f():", '    """' + "Doc.\n" * 10 + '    """'] + ["    x = 1"] * LIMIT + ["    return x"]
    node = ast.parse("\n".join(lines)).body[0]
    assert body_lines(node) == LIMIT + 1

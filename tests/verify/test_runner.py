"""The table and the ``mitsnerf check`` command (on the fast deterministic cases only)."""

import dataclasses

import pytest

from mitsnerf import cli
from mitsnerf.verify import cases as C
from mitsnerf.verify.runner import CaseResult, format_table, run_checks


def test_run_checks_runs_the_named_cases_and_the_table_has_a_row_each():
    results = run_checks("quick", only=["closed_form", "grad_color"])
    assert [r.name for r in results] == ["closed_form", "grad_color"]
    assert all(r.passed for r in results)
    table = format_table(results)
    header, rule, *rows = table.splitlines()
    assert header.split()[:3] == ["case", "reference", "measured"] and set(rule) <= {"-", " "}
    assert len(rows) == 2 and all(" pass " in row for row in rows)


def test_unknown_case_and_quality_are_errors_that_list_the_choices():
    with pytest.raises(ValueError, match="known: closed_form"):
        run_checks("quick", only=["nope"])
    with pytest.raises(ValueError, match="quick, thorough"):
        run_checks("fast")


def test_info_rows_and_failures_are_marked_and_explained():
    rows = [CaseResult("a", "r", "e", 1.5, "0/3", None, 0.1, "recorded"),
            CaseResult("b", "r", "e", None, "-", False, 0.2, "why it failed")]
    table = format_table(rows)
    assert " info " in table and " FAIL " in table
    assert "a: recorded" in table and "b: why it failed" in table


def test_cli_check_exits_zero_when_all_pass_and_one_on_a_failure(monkeypatch, capsys):
    assert cli.main(["check", "--case", "closed_form", "--no-progress"]) == 0
    assert "closed_form" in capsys.readouterr().out
    monkeypatch.setattr(C, "CLOSED_FORM", dataclasses.replace(C.CLOSED_FORM, rtol=0.0))
    assert cli.main(["check", "--case", "closed_form", "--no-progress"]) == 1
    captured = capsys.readouterr()
    assert " FAIL " in captured.out and "1 case(s) failed: closed_form" in captured.err


def test_cli_check_rejects_an_unknown_case(capsys):
    assert cli.main(["check", "--case", "nope", "--no-progress"]) == 2
    assert "unknown case" in capsys.readouterr().err

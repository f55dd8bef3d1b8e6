"""The table, the mutation matrix and the ``mitsnerf check`` command (on the fast deterministic cases only)."""

import dataclasses

import pytest

from mitsnerf import cli
from mitsnerf.verify import cases as C
from mitsnerf.verify.mutations import MUTATIONS
from mitsnerf.verify.runner import CaseResult, count_line, format_mutations, format_table, run_checks, run_mutations


def test_run_checks_runs_the_named_cases_and_the_table_has_a_row_each():
    results = run_checks("quick", only=["closed_form", "grad_color"])
    assert [r.name for r in results] == ["closed_form", "grad_color"]
    assert all(r.passed for r in results)
    header, rule, *rows = format_table(results, wide=True).splitlines()
    assert header.split()[:4] == ["case", "checks", "reference", "measured"] and set(rule) <= {"-", " "}
    assert len(rows) == 2 and all(" pass " in row for row in rows)
    header = format_table(results).splitlines()[0]
    assert header.split() == ["case", "checks", "result", "max|z|", "rejected", "time", "measured", "error"]


def test_unknown_case_and_quality_are_errors_that_list_the_choices():
    with pytest.raises(ValueError, match="known: closed_form"):
        run_checks("quick", only=["nope"])
    with pytest.raises(ValueError, match="quick, thorough"):
        run_checks("fast")


def test_info_rows_failures_and_notes_are_marked_and_explained():
    rows = [CaseResult("a", "record", "r", "e", 1.5, "0/3", None, 0.1, note="recorded"),
            CaseResult("b", "integrator", "r", "e", None, "2/15", False, 0.2, "why it failed")]
    table = format_table(rows, alpha=0.001)
    assert " info " in table and " FAIL " in table
    assert "a: recorded" in table and "b: why it failed" in table and "probability at most 0.001" in table
    assert "Reading mitsnerf check" in table and "Holm" not in table


def test_the_count_line_counts_passes_and_failures_not_records():
    rows = [CaseResult("a", "record", "r", "e", 1.5, "0/3", None, 0.1),
            CaseResult("b", "integrator", "r", "e", None, "2/15", False, 0.2, "why"),
            CaseResult("c", "formula", "r", "e", None, "-", True, 0.1)]
    assert count_line(rows) == "1 passed, 1 failed"


def test_the_mutation_matrix_names_the_cases_that_catch_each_mutation():
    muts = [MUTATIONS["T_off_by_one"], MUTATIONS["jitter_frozen"]]
    report = run_mutations("quick", muts, only=["closed_form", "sampler_jitter", "grad_color"])
    assert [r.name for r in report.clean] == ["closed_form", "sampler_jitter", "grad_color"]
    assert [r.name for r in report.caught_by("T_off_by_one")] == ["closed_form"]
    assert [r.name for r in report.caught_by("jitter_frozen")] == ["sampler_jitter"]
    assert report.passed and not report.escaped
    text = format_mutations(report)
    assert "composite.weights" in text and "schedule.step_rng" in text and "sampler_jitter (steps independent)" in text


def test_a_mutation_no_case_catches_is_reported():
    report = run_mutations("quick", [MUTATIONS["T_detached"]], only=["closed_form"])
    assert report.escaped == ["T_detached"] and not report.passed
    assert "NOT CAUGHT" in format_mutations(report)


def test_cli_check_exits_zero_when_all_pass_and_one_on_a_failure(monkeypatch, capsys):
    assert cli.main(["check", "--case", "closed_form", "--no-progress"]) == 0
    assert "closed_form" in capsys.readouterr().out
    monkeypatch.setattr(C, "CLOSED_FORM", dataclasses.replace(C.CLOSED_FORM, rtol=0.0))
    assert cli.main(["check", "--case", "closed_form", "--no-progress"]) == 1
    captured = capsys.readouterr()
    assert " FAIL " in captured.out and "1 case(s) failed: closed_form" in captured.err


def test_cli_check_mutations_prints_the_matrix_and_fails_when_a_mutation_escapes(capsys):
    # closed_form alone cannot see gradient or jitter bugs: those escape, so the exit status is 1.
    assert cli.main(["check", "--mutations", "--case", "closed_form", "--no-progress"]) == 1
    captured = capsys.readouterr()
    assert "caught by" in captured.out and "NOT CAUGHT" in captured.out
    assert "caught by no case: jitter_ignored" in captured.err


def test_cli_check_rejects_an_unknown_case(capsys):
    assert cli.main(["check", "--case", "nope", "--no-progress"]) == 2
    assert "unknown case" in capsys.readouterr().err


def test_a_failing_check_ends_with_its_count_line_after_the_failure_line(monkeypatch):
    """stdout and stderr on one terminal: the count line was followed by the stderr failure line."""
    import io
    import sys

    both = io.StringIO()
    monkeypatch.setattr(sys, "stdout", both)
    monkeypatch.setattr(sys, "stderr", both)
    monkeypatch.setattr(C, "CLOSED_FORM", dataclasses.replace(C.CLOSED_FORM, rtol=0.0))
    assert cli.main(["check", "--case", "closed_form", "--no-progress"]) == 1
    lines = both.getvalue().splitlines()
    assert lines[-1] == "0 passed, 1 failed" and "1 case(s) failed: closed_form" in lines[-2]


def test_the_words_of_the_notes_are_explained_under_them():
    rows = [CaseResult("box", "integrator", "r", "e", 6.3, "0/3", True, 0.1,
                       note="seed's rule against volpath as it is (its first-order exit bias, not a test): "
                            "relative +1.7e-03, channel-mean z +6.3"),
            CaseResult("train_average", "training path", "r", "e", 1.0, "0/3", True, 0.1,
                       note="N = 512 (seed's rule, training jitter)")]
    table = format_table(rows, alpha=0.001).split("Words in the notes:\n")[1].splitlines()
    assert [line.split(":")[0] for line in table] == ["seed's rule", "z", "N", "jitter"]
    assert "Words in the notes" not in format_table(rows[:0] + [CaseResult("c", "f", "r", "e", None, "-", True, 0.1)])


# Rows as wide as the thorough run's in docs/notes/verification.md: a 70-character reference, a 110-character error.
WIDE_ROWS = [
    CaseResult("exit_single_scatter", "integrator", "volpath 16384 spp, max_depth 2 " + "x" * 40,
               "rel. mean 4.2e-04 (<= 0.02), mean z -0.75; " + "a measured figure, " * 4, 4.30, "0/1731", True, 1224.2,
               note="seed's rule against volpath as it is (its first-order exit bias, not a test): relative +2.5e-03, "
                    "channel-mean z +5.6, at N = 64 and N = 128 in the exit-heavy medium"),
    CaseResult("closed_form", "training path", "closed forms; orders over N = 8..64",
               "max rel 1.4e-06 (<= 2e-05); orders 2.07 (2), 0.98 (1), midpoint 2.00 (2)", None, "-", True, 0.0),
]


def test_the_default_table_fits_100_columns_and_wide_keeps_each_row_on_one_line():
    """The rows were 255 characters wide: every terminal wrapped them into noise."""
    compact = format_table(WIDE_ROWS, alpha=0.001).split("\n\n")[0]  # the table; the notes follow, one line each
    assert max(map(len, compact.splitlines())) <= 100
    assert "volpath 16384 spp" not in compact  # the reference is the wide table's
    assert "a measured figure, a measured figure" in " ".join(compact.split())  # the error is all there, wrapped
    wide = format_table(WIDE_ROWS, alpha=0.001, wide=True).splitlines()
    assert len(wide[2]) > 200 and wide[2].startswith("exit_single_scatter") and "volpath 16384 spp" in wide[2]


def test_cli_check_prints_the_compact_table_and_writes_the_wide_one_under_out(tmp_path, capsys):
    assert cli.main(["check", "--case", "closed_form", "--no-progress", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "reference" not in printed.splitlines()[0] and max(map(len, printed.split("\n\n")[0].splitlines())) <= 100
    written = (tmp_path / "check.txt").read_text().splitlines()
    assert written[0].split()[:3] == ["case", "checks", "reference"] and written[-1] == "1 passed, 0 failed"
    assert "closed forms; orders over N = 8..64" in written[2]
    assert cli.main(["check", "--case", "closed_form", "--no-progress", "--wide"]) == 0
    assert capsys.readouterr().out.splitlines()[0].split()[:3] == ["case", "checks", "reference"]


def test_check_help_does_not_promise_a_minute(capsys):
    """It said "about a minute"; the quick suite takes minutes on a 2-core machine."""
    with pytest.raises(SystemExit):
        cli.main(["check", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "about a minute" not in text and "a few minutes on 2 cores" in text and "--wide" in text

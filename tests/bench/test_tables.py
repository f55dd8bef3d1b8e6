"""Tables: means over seeds, best per scene marked, averages over scenes, failures noted."""

from __future__ import annotations

import pytest

from mitsnerf.bench.tables import BEST, QUALITY, average_rows, csv_table, markdown_table, scene_rows


def _record(scene, method, seed, psnr, rel_l1):
    return {"scene": scene, "method": method, "seed": seed,
            "metrics": {"psnr_test": psnr, "density_rel_l1": rel_l1, "psnr_test_per_view": [psnr], "density_note": None}}


RECORDS = [_record("a", "m1", 0, 30.0, 0.2), _record("a", "m1", 1, 32.0, 0.4), _record("a", "m2", 0, 29.0, 0.1),
           _record("b", "m1", 0, 20.0, 0.5), _record("b", "m2", 0, 25.0, 0.6)]


def test_rows_are_means_over_seeds_in_config_order():
    rows = scene_rows(RECORDS, scenes=["b", "a"], methods=["m2", "m1"])
    assert [(r["scene"], r["method"]) for r in rows] == [("b", "m2"), ("b", "m1"), ("a", "m2"), ("a", "m1")]
    a_m1 = rows[3]
    assert a_m1["seeds"] == 2 and a_m1["psnr_test"] == 31.0 and a_m1["psnr_test_std"] == pytest.approx(2 ** 0.5)
    assert "psnr_test_per_view" not in a_m1  # lists stay in the JSON records


def test_best_is_marked_per_scene_and_in_the_right_direction():
    rows = scene_rows(RECORDS, scenes=["a", "b"], methods=["m1", "m2"])
    md = markdown_table(rows, QUALITY, BEST, group="scene").splitlines()
    a_m1, a_m2, b_m1, b_m2 = md[2:6]
    assert "**31.00**" in a_m1 and "**0.100**" in a_m2  # PSNR: max; density error: min
    assert "**25.00**" in b_m2 and "**0.500**" in b_m1


def test_average_over_scenes_and_failures():
    failed = [{"scene": "b", "method": "m2", "seed": 1, "key": "b/m2-seed1", "error": "boom"}]
    rows = scene_rows(RECORDS, failed, scenes=["a", "b"], methods=["m1", "m2"])
    avg = average_rows(rows, ["m1", "m2"])
    assert [r["method"] for r in avg] == ["m1", "m2"]
    assert avg[0]["psnr_test"] == pytest.approx((31.0 + 20.0) / 2) and avg[1]["psnr_test"] == pytest.approx(27.0)
    assert rows[-1]["note"] == "1 failed" and avg[1]["note"] == "1 failed"


def test_csv_has_a_header_and_one_line_per_row():
    text = csv_table(scene_rows(RECORDS), ["scene", "method", "psnr_test"])
    assert text.splitlines()[0] == "scene,method,psnr_test" and len(text.splitlines()) == 5


def test_peak_memory_is_marked_only_when_every_cell_had_a_fresh_process():
    from mitsnerf.bench.tables import best_rules

    fresh = [{"worker": {"fresh_process": True}}] * 2
    assert "peak_rss_mb" in best_rules(fresh)
    assert "peak_rss_mb" not in best_rules(fresh + [{"worker": {"fresh_process": False}}])


def test_every_seconds_to_target_column_is_best_at_its_minimum():
    from mitsnerf.bench.tables import BEST, best_values

    rows = [{"scene": "a", "seconds_to_33db": 5.0, "seconds_to_40db": 9.0},
            {"scene": "a", "seconds_to_33db": 2.0, "seconds_to_40db": 12.0}]
    marks = best_values(rows, BEST, group="scene")
    assert marks[("a", "seconds_to_33db")] == 2.0 and marks[("a", "seconds_to_40db")] == 9.0


def test_ties_at_the_displayed_precision_are_all_bold_whatever_the_order():
    """A sequential --quick printed ngp and its subclass both at 25.87 dB, only one of them bold."""
    from mitsnerf.bench.report import html_table

    rows = [{"scene": "a", "method": "ngp", "psnr_test_medium": 25.8712},
            {"scene": "a", "method": "sub", "psnr_test_medium": 25.8698},
            {"scene": "a", "method": "nerf", "psnr_test_medium": 25.86}]
    for order in (rows, rows[::-1]):
        md = markdown_table(order, QUALITY, BEST, group="scene")
        bold = {line.split(" | ")[1] for line in md.splitlines()[2:] if "**" in line}
        assert bold == {"ngp", "sub"}, md
        assert html_table(order, QUALITY, "scene", BEST).count('class="best"') == 2


def test_the_legend_has_one_line_per_column_and_says_what_bold_means():
    from mitsnerf.bench.tables import COMPACT, cost_columns, legend

    lines = legend(COMPACT).splitlines()
    assert [line.split(":")[0] for line in lines] == [f"- {h}" for _, h, _ in COMPACT] + ["- bold"]
    full = legend(QUALITY + cost_columns([{"seconds_to_35db": 1.0}]))
    assert "- ref agreement:" in full and "- s to X dB medium:" in full and "GT floor" not in full
    assert all(len(line) < 250 for line in full.splitlines())


def test_the_printed_table_is_compact_and_says_what_a_perfect_model_scores():
    from mitsnerf.bench.tables import PERFECT_DB, compact_report, oracle_row, with_oracle_rows

    rows = scene_rows([{**r, "metrics": {**r["metrics"], "noise_floor_psnr_medium": 40.0}} for r in RECORDS])
    ceiling = oracle_row("a", {"psnr_test_medium": 41.5}, {})
    text = compact_report(with_oracle_rows(rows, [ceiling]), average_rows(rows))
    header = next(line for line in text.splitlines() if line.startswith("| scene"))
    assert header == "| scene | method | budget | train s | PSNR medium | gap to oracle | SSIM | sigma rel L1 |"
    assert f"a: two reference renders agree to 40.00 dB (medium pixels): a perfect model would score about " \
           f"{40 + PERFECT_DB:.2f} dB; the oracle scores 41.50 dB." in text
    assert PERFECT_DB == pytest.approx(3.0103, abs=1e-4)

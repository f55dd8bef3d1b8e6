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
    assert marks[(("a", "images"), "seconds_to_33db")] == 2.0 and marks[(("a", "images"), "seconds_to_40db")] == 9.0


def test_bold_compares_the_rows_that_were_given_the_same():
    """The legend says to compare rows given the same: scatter (given the lights too) is bold among such rows, not
    over those given the images alone (it used to be bolded best against them); each group has its own best."""
    from mitsnerf.bench.report import html_table
    from mitsnerf.bench.tables import legend

    lit = "images, lights, phase function"
    rows = [{"scene": "a", "method": "ngp", "given": "images", "psnr_test_medium": 40.0},
            {"scene": "a", "method": "voxel", "given": "images", "psnr_test_medium": 39.0},
            {"scene": "a", "method": "scatter", "given": lit, "psnr_test_medium": 45.0},
            {"scene": "a", "method": "mitsuba-inverse", "given": lit, "psnr_test_medium": 30.0},
            {"scene": "a", "method": "tool (external)", "psnr_test_medium": 41.0}]
    md = markdown_table(rows, QUALITY, BEST, group="scene")
    bold = {line.split(" | ")[1] for line in md.splitlines()[2:] if "**" in line}
    assert bold == {"tool (external)", "scatter"}, md  # another tool's renders were given the images
    assert html_table(rows, QUALITY, "scene", BEST).count('class="best"') == 2
    assert "among the rows given the same" in legend(QUALITY)


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
    assert header == ("| scene | method | given | budget | train s | PSNR medium | gap to oracle | its ceiling | "
                      "gap to its ceiling | SSIM | sigma rel L1 | peak MiB | model MB |")
    assert f"a: two reference renders agree to 40.00 dB (medium pixels): a perfect model would score about " \
           f"{40 + PERFECT_DB:.2f} dB; the oracle scores 41.50 dB." in text
    assert PERFECT_DB == pytest.approx(3.0103, abs=1e-4)


# --------------------------------------------------------------------------- a ceiling a row beats; a quick table

QUICK_ORACLE = {"config": {"spp": 8, "resolution": 16, "n_samples": 128}, "footprint": 1,
                "mc_error": {"lbar_rel_se_median": 0.138}, "directional": {"g": 0.85, "order": 2}}


def _scene(oracle: float, floor: float, methods: dict[str, float]):
    """Per-scene rows of scene "hg" as ``bench physics --quick`` printed them: an oracle row and method rows."""
    from mitsnerf.bench.tables import oracle_row, with_oracle_rows

    records = [{"scene": "hg", "method": m, "seed": 0,
                "metrics": {"psnr_test_medium": p, "noise_floor_psnr_medium": floor, "ssim_test": -0.0033}}
               for m, p in methods.items()]
    ceiling = oracle_row("hg", {"psnr_test_medium": oracle, "noise_floor_psnr_medium": floor}, QUICK_ORACLE)
    return with_oracle_rows(scene_rows(records, scenes=["hg"], methods=list(methods)), [ceiling])


def test_a_ceiling_a_row_beats_is_never_printed_without_the_reason_beside_it():
    """bench physics --quick printed nerf 1.28 dB above cloud_hg85's oracle with no word of why."""
    from mitsnerf.bench.tables import compact_report, markdown_report

    rows = _scene(14.90, 17.98, {"ngp": 13.40, "nerf": 16.17})
    for text in (compact_report(rows, average_rows(rows)), markdown_report(rows, average_rows(rows))):
        assert "| hg | oracle (ceiling, beaten: see below) |" in text
        line = next(x for x in text.splitlines() if x.startswith("hg: two reference renders"))
        assert ("the oracle scores 14.90 dB; nerf 16.17 above it: this ceiling is an estimate (J from 8 volpath "
                "directions per point of a 16^3 grid, median relative error 14%, to spherical-harmonic order 2 for "
                "g = 0.85), below the true one") in line and "ngp" not in line


def test_an_oracle_above_the_perfect_model_figure_says_why():
    """The smoke's quick oracle (20.85 dB) above "a perfect model would score about 20.39 dB", unexplained."""
    from mitsnerf.bench.tables import compact_report

    text = compact_report(*(lambda r: (r, average_rows(r)))(_scene(20.85, 17.38, {"nerf": 20.35})))
    line = next(x for x in text.splitlines() if x.startswith("hg: "))
    assert "a perfect model would score about 20.39 dB; the oracle scores 20.85 dB, above that perfect-model " \
           "figure: both are estimates" in line
    assert "| hg | oracle (ceiling) |" in text  # no row above it


def test_a_ceiling_above_every_row_reads_as_before():
    from mitsnerf.bench.tables import reference_lines

    (line,) = reference_lines(_scene(24.10, 22.42, {"nerf": 20.16}))
    assert line.endswith("a perfect model would score about 25.43 dB; the oracle scores 24.10 dB.")


def test_a_quick_table_says_it_is_a_smoke_test_first():
    from mitsnerf.bench.tables import compact_report, markdown_report, quick_banner

    rows = _scene(24.10, 22.42, {"nerf": 20.16})
    banner = quick_banner("16x16 views, 2 test views at 16 spp, 30 steps")
    for text in (compact_report(rows, average_rows(rows), quick=banner),
                 markdown_report(rows, average_rows(rows), quick=banner)):
        assert text.startswith("Quick profile (16x16 views, 2 test views at 16 spp, 30 steps): a smoke test")
        assert "SSIM below 0" in text.split("\n")[0]
    assert not compact_report(rows, average_rows(rows)).startswith("Quick")


def test_every_table_shows_each_cells_own_peak_memory_and_its_models_size():
    from mitsnerf.bench.tables import COMPACT, compact_report, markdown_report

    records = [{**r, "metrics": {**r["metrics"], "peak_memory_mb": 100.0 + i, "model_bytes": 224_000 * (i + 1)}}
               for i, r in enumerate(RECORDS)]
    rows = scene_rows(records)
    assert rows[0]["model_mb"] == pytest.approx((0.224 + 0.448) / 2) and rows[0]["peak_memory_mb"] == 100.5
    for text in (compact_report(rows, average_rows(rows)), markdown_report(rows, average_rows(rows))):
        header = next(line for line in text.splitlines() if "peak MiB" in line)
        assert "model MB" in header and "- peak MiB: the cell's own peak memory" in text
    lines = compact_report(rows, average_rows(rows)).splitlines()
    a_m1, a_m2 = (next(line for line in lines if f"| a | {m} |" in line) for m in ("m1", "m2"))
    assert a_m1.endswith("| **100** | **0.336** |") and a_m2.endswith("| 102 | 0.672 |")  # the least of a scene: bold
    assert ("peak_memory_mb", "peak MiB", 0) in COMPACT


# --------------------------------------------------------------------------- ceilings that are ceilings

def _noisy_ceiling_table(mc: float):
    """A scene whose oracle is a Monte Carlo estimate with noise ``mc`` per pixel (two independent renders of it),
    the references with noise 0.02, and a method whose renders miss the truth by a deterministic 0.015: the rows as
    the bench builds them, through the shared scoring (score_views, the rung's ceiling)."""
    import numpy as np

    from mitsnerf.bench.tables import oracle_row, with_oracle_rows
    from mitsnerf.math.box import UNIT_BOX
    from mitsnerf.oracle.rungs import ceiling_figures
    from mitsnerf.scoring.images import image_scores
    from mitsnerf.scoring.reference import Reference
    from mitsnerf.scoring.variance import pair_variance
    from mitsnerf.scoring.views import score_views

    rng = np.random.default_rng(3)
    truth = rng.uniform(0.2, 0.8, size=(4, 32, 32, 3))
    refs = truth + rng.normal(0.0, 0.02, truth.shape)
    ref = Reference(refs, (), 0.5, UNIT_BOX, None, np.ones(truth.shape[:3], bool), {"psnr_medium": 31.0})
    a, b = (truth + rng.normal(0.0, mc, truth.shape) for _ in range(2))
    oracle = score_views(a, ref, variance=pair_variance(a, b))[0]
    method = score_views(truth + 0.015 * rng.choice([-1.0, 1.0], truth.shape), ref, oracle=oracle)[0]
    method.update(ceiling_figures("emission-absorption", None, None, None, 1, ref, method))
    rows = scene_rows([{"scene": "s", "method": "m", "seed": 0, "metrics": method}])
    truth_psnr = image_scores(truth, refs, ref.masks)["psnr_test_medium"]
    return with_oracle_rows(rows, [oracle_row("s", oracle, {})]), oracle, method, truth_psnr


def test_a_noisy_ceiling_is_no_longer_under_the_row_it_caps():
    """The oracle's own Monte Carlo noise (0.03 a pixel, above the method's 0.015 error) puts its raw PSNR under a
    method it caps: less that variance (two independent renders) it is the noise-free truth's score, the table shows
    it above the row, beside its raw figure, and no row is above its ceiling."""
    from mitsnerf.bench.tables import above_ceiling, compact_report, markdown_report

    rows, oracle, method, truth_psnr = _noisy_ceiling_table(0.03)
    assert oracle["psnr_test_medium"] < method["psnr_test_medium"] - 1.0        # the planted noisy ceiling
    assert oracle["psnr_test_medium_without_mc"] == pytest.approx(truth_psnr, abs=0.2)
    assert method["gap_to_oracle"] == pytest.approx(oracle["psnr_test_medium_without_mc"] - method["psnr_test_medium"])
    assert method["gap_to_ceiling"] > 0.5 and all(above_ceiling(r) is None for r in rows)
    shown = f"{oracle['psnr_test_medium_without_mc']:.2f} (raw {oracle['psnr_test_medium']:.2f})"
    for text in (compact_report(rows, average_rows(rows)), markdown_report(rows, average_rows(rows))):
        rows_and_notes = [line for line in text.splitlines() if line.startswith(("s m: ", "| s | m |"))]
        assert "| s | oracle (ceiling) |" in text and "beaten" not in text
        assert rows_and_notes and not [line for line in rows_and_notes if "above its ceiling" in line]
        assert shown in next(line for line in text.splitlines() if line.startswith("| s | m |"))  # its ceiling
        assert shown in next(line for line in text.splitlines() if line.startswith("| s | oracle (ceiling) |"))
        assert f"the oracle scores {oracle['psnr_test_medium_without_mc']:.2f} dB less its own Monte Carlo " \
               f"variance (raw {oracle['psnr_test_medium']:.2f} dB)" in text


def test_a_row_above_a_ceiling_whose_variance_was_not_removed_says_why_in_its_note():
    """The same noisy ceiling cached without its variance (an older oracle): the row is above it, and its note (the
    lines under the printed table) says by how much and why; every row above its ceiling has a reason."""
    from mitsnerf.bench.tables import above_ceiling, compact_report, with_ceiling_reasons

    rows, oracle, _, _ = _noisy_ceiling_table(0.03)
    raw = [{k: v for k, v in r.items() if not k.endswith("_without_mc")} for r in rows]
    raw[1]["ceiling_note"] = "the oracle, raw: no estimate of its own Monte Carlo variance was kept"
    assert above_ceiling(raw[1]) is not None
    explained = with_ceiling_reasons(raw)
    for row in explained:
        assert above_ceiling(row) is None or "above its ceiling" in (row.get("note") or "")
    assert with_ceiling_reasons(explained) == explained                          # applied twice, said once
    from mitsnerf.bench.report import html_table

    assert "above its ceiling" in html_table(explained, QUALITY, "scene", BEST)  # the report's note column too
    text = compact_report(raw, average_rows(raw))
    line = next(x for x in text.splitlines() if x.startswith("s m: "))
    assert f"; above its ceiling {oracle['psnr_test_medium']:.2f} by " in line
    assert "no estimate of its own Monte Carlo variance was kept; its own Monte Carlo variance, not removed, " \
           "lowers it" in line

"""bench addon-fit (devtools/bench/addon_fit.py): the add-on's Fit against the fit command."""
import json

import pytest

from devtools.bench import addon_fit


def row(round_, way, wall, fit, loss=1.5, **addon):
    return {"round": round_, "way": way, "wall_s": wall, "fit_s": fit, "loss": loss, **addon}


def test_the_summary_gives_the_medians_their_ratio_per_round_and_the_add_ons_time_beyond_its_fit():
    rows = [row(1, "cli", 100.0, 98.0), row(1, "addon", 110.0, 97.0, operator_s=109.0, material_s=11.0,
                                           node_group_s=10.0),
            row(2, "addon", 104.0, 99.0, operator_s=103.0, material_s=2.0, node_group_s=1.5),
            row(2, "cli", 96.0, 94.0), row(3, "cli", 90.0, 0.0) | {"error": "no result"}]
    s = addon_fit.summary(rows)
    assert (s["rounds"], s["failed"]) == (3, 1)
    assert (s["cli_median_s"], s["addon_median_s"]) == (98.0, 107.0)
    assert s["ratio"] == round(107.0 / 98.0, 3) and s["round_ratios"] == [1.1, round(104 / 96, 3)]
    assert s["beyond_fit_s"] == 8.0          # the medians of 12 and 4 s of operator beyond the fit
    assert (s["material_s"], s["node_group_s"]) == (6.5, 5.75)
    assert s["losses"] == [1.5]
    assert "add-on 107.0 s / command line 98.0 s = 1.092" in addon_fit.format_summary(s)
    assert addon_fit.summary([row(1, "cli", 100.0, 98.0)]) == {"rounds": 1, "failed": 0}   # no add-on fit: no ratio


@pytest.mark.slow
@pytest.mark.blender
def test_one_round_fits_the_example_from_the_add_on_and_from_the_command_line_alike(capsys):
    """A short fit (2 steps at 64 px, the weave given) each way: both fit the same loss, and the add-on's
    row has its operator's and its material's times (it ran the installed zip's Fit operator)."""
    from addon_support import require_bpy
    require_bpy()
    assert addon_fit.bench_addon_fit(None, None, rounds=1, iterations=2, size=64, as_json=True,
                                     pattern="twill1") == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")]
    rows, s = lines[:-1], lines[-1]
    assert [r["way"] for r in rows] == ["cli", "addon"] and s["failed"] == 0
    addon = rows[1]
    assert addon["operator_s"] >= addon["fit_s"] > 0 and 0 < addon["node_group_s"] <= addon["material_s"]
    assert len(s["losses"]) == 1             # the same fit either way

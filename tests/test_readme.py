"""The main job (`lmncell demo`) on the shipped data, and the README's claims against it: the
generated figures block and the FMU's variable table."""

from __future__ import annotations

import json
import re
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import pytest
from lmncell.cli import main
from lmncell.report.readme import figures_block, numbers, power_of_ten_above, render_figures

from tests.conftest import ROOT

README = ROOT / "README.md"


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("demo")
    assert main(["demo", "--out", str(out)]) == 0
    return out


def test_demo_writes_report_figures_and_summary(demo) -> None:
    html = (demo / "report.html").read_text(encoding="utf-8")
    for fig in re.findall(r'<img src="([^"]+)"', html):
        assert (demo / fig).stat().st_size > 5_000, fig
    assert "`" not in html                                  # code spans, not backticks
    assert "RMSE whole record" in html and "RMSE 20–80 % SoC" in html
    summary = json.loads((demo / "summary.json").read_text())
    soc = summary["soc_rmse_pct_from_0_6_with_0_3"]
    assert set(soc) == {"ekf", "fuzzy", "imm", "coulomb"}
    assert max(soc["ekf"], soc["fuzzy"], soc["imm"]) < soc["coulomb"] / 3
    outside = summary["soc_outside_3sigma_pct"]
    assert set(outside) == {"ekf", "fuzzy", "imm"}
    assert max(outside.values()) <= 5.0                   # the bands hold the truth (issue)
    assert summary["fmu_max_dv_v"] < 1e-9
    whole, window = summary["validation_rmse_mv"], summary["validation_window_rmse_mv"]
    assert set(whole) == set(window) and all(whole[k] >= window[k] for k in whole)
    # the model file, baselines and all, holds no wall-clock time and no folder of the data
    model_text = (demo / "a123_lmn.json").read_text(encoding="utf-8")
    assert '"baselines"' in model_text and "seconds" not in model_text
    assert str(ROOT) not in model_text and "A123_DYN_50_P45_s1.csv" in model_text
    with zipfile.ZipFile(demo / "A123_LMNCell.fmu") as z:
        doc = z.read("documentation/index.html").decode()
    assert "<li>A123_OCV_P25_S1.csv.gz (slow OCV test) <small>sha256" in doc


def test_the_reports_local_models_are_what_explain_prints(demo, capsys) -> None:
    """The report's table of local models is `lmncell explain` at the reference temperature
    (it said plain `lmncell explain MODEL`, which states each at its own centre: 15 °C)."""
    html = (demo / "report.html").read_text(encoding="utf-8")
    assert "lmncell explain MODEL --temperature 25</code> prints the same" in html
    assert main(["explain", str(demo / "a123_lmn.json"), "--temperature", "25", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    for row in rows:
        assert f"<td>{row['r0_mohm']:.1f}</td><td>{row['r_static_mohm']:.1f}</td>" in html


def test_readme_figures_are_the_demo_figures(demo) -> None:
    """The README's figures block is what `python -m lmncell.report.readme` renders from this
    code's demo (numbers within 2 % or 0.05: last digits may differ between BLAS builds)."""
    summary = json.loads((demo / "summary.json").read_text())
    mine = numbers(figures_block(README.read_text(encoding="utf-8")))
    now = numbers(render_figures(summary))
    assert len(mine) == len(now), "regenerate: python -m lmncell.report.readme SUMMARY README"
    for a, b in zip(mine, now, strict=True):
        assert a == pytest.approx(b, rel=0.02, abs=0.05), (
            f"README says {a}, the demo gives {b}: run `lmncell demo` and "
            "`python -m lmncell.report.readme lmncell-demo/summary.json README.md`")
    bound = power_of_ten_above(summary["fmu_max_dv_v"])
    assert f"reproduces the pipeline within {bound} V." in README.read_text(encoding="utf-8")


def test_the_fmus_difference_is_quoted_as_a_bound_that_last_bits_do_not_move() -> None:
    """One or two units in the last place at 3.3 V (4.4e-16, 8.9e-16 V: two machines' demo
    runs) give the README the same sentence; a larger difference a larger bound."""
    assert power_of_ten_above(4.4e-16) == power_of_ten_above(8.9e-16) == "1e-15"
    assert power_of_ten_above(1.1e-15) == "1e-14"
    assert power_of_ten_above(1e-12) == "1e-12"
    assert power_of_ten_above(0.0) == "0"


def test_readme_fmu_table_lists_the_fmu_variables(demo) -> None:
    fmu = next(demo.glob("*_LMNCell.fmu"))
    with zipfile.ZipFile(fmu) as z:
        root = ET.fromstring(z.read("modelDescription.xml"))
    actual = {}
    for sv in root.iter("ScalarVariable"):
        unit = next(iter(sv)).get("unit", "–")
        actual[sv.get("name")] = (sv.get("causality"), unit)
    text = README.read_text(encoding="utf-8")
    table = text[text.index("| variable | causality |"):]
    rows = re.findall(r"^\| `(\w+)` \| (\w+) \| ([^|]+) \|", table, flags=re.M)
    documented = {name: (causality, unit.strip()) for name, causality, unit in rows}
    assert documented == actual


def test_readme_update_names_a_missing_or_wrong_file(tmp_path, capsys) -> None:
    """The maintainer's command that regenerates the README's figures refuses a missing file
    or a summary that is not the demo's with a message naming it, not a traceback."""
    from lmncell.report.readme import main as readme_main

    missing = tmp_path / "README.md"
    summary = tmp_path / "summary.json"
    summary.write_text("{}", encoding="utf-8")
    assert readme_main([str(summary), str(missing)]) == 2
    assert str(missing) in capsys.readouterr().err
    missing.write_text("no figures block here\n", encoding="utf-8")
    assert readme_main([str(summary), str(missing)]) == 2
    assert "summary.json" in capsys.readouterr().err
    assert readme_main([]) == 2

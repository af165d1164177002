"""Reports render: valid GitHub-flavoured Markdown and a self-contained HTML beside every report.md.

The Markdown checks use their own reading of the GFM spec (tables extension: a row is split on
every pipe not escaped by a backslash, code spans included), independent of the workbench's
helpers, so a helper that forgot an escape fails here. Every report is produced by its command
(verify, calibrate, selfsense through the CLI; the study through its writer in full runs) with
a relative ``--out``, the case where links used to point at ``out/x/x.png`` from inside ``out/x``.
"""

import json
import re
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ..conftest import FULL, PLANTS
from workbench.report.html import markdown_to_html, split_table_row, write_html_report
from workbench.report.markdown import md_image, md_row, md_table, readable_quantity

ROOT = Path(__file__).resolve().parents[2]
# a metric key leaking into a table: snake_case words ending in one of the workbench's unit suffixes
RAW_KEY = re.compile(r"(?<![\w.])[a-z][a-z0-9]+(?:_[a-z0-9]+)*_(?:v|s|m|a|hz|n|percent|deg|db|ohm|f|fraction|points|rad)"
                     r"(?![\w.])")
VOID = {"meta", "img", "br", "hr", "link", "input", "col", "area", "base", "source", "wbr"}


def gfm_cells(line):
    """GFM's cells of a table line (leading/trailing pipe optional; ``\\|`` is a literal pipe)."""
    s = line.strip()
    s = s[1:] if s.startswith("|") else s
    s = s[:-1] if s.endswith("|") and not s.endswith("\\|") else s
    return [c.replace("\x00", "|").strip() for c in s.replace("\\|", "\x00").split("|")]


def markdown_problems(path):
    """Everything that keeps ``path`` from rendering as meant on GitHub (empty list: none)."""
    path = Path(path)
    lines = path.read_text(encoding="utf-8").splitlines()
    problems, in_code = [], False
    delim = re.compile(r"^\|?\s*:?-+:?\s*(\|\s*:?-+:?\s*)*\|?$")
    i = 0
    while i < len(lines):
        if lines[i].strip().startswith("```"):
            in_code = not in_code
        if not in_code and i + 1 < len(lines) and "|" in lines[i] and delim.match(lines[i + 1].strip()):
            width = len(gfm_cells(lines[i]))
            if len(gfm_cells(lines[i + 1])) != width:
                problems.append(f"line {i + 2}: delimiter row has {len(gfm_cells(lines[i + 1]))} cells, header {width}")
            j = i + 2
            while j < len(lines) and lines[j].strip() and "|" in lines[j]:
                cells = gfm_cells(lines[j])
                if len(cells) != width:
                    problems.append(f"line {j + 1}: {len(cells)} cells, header {width}: {lines[j]}")
                for c in cells + gfm_cells(lines[i]):
                    for key in RAW_KEY.findall(re.sub(r"`[^`]*`", "", c)):
                        problems.append(f"line {j + 1}: raw key {key!r} in a table cell")
                j += 1
            i = j
            continue
        i += 1
    for target in re.findall(r"!\[[^\]]*\]\(([^)]*)\)", "\n".join(lines)):
        if not target or re.match(r"^[a-z]+:|^/", target):
            problems.append(f"image link {target!r} is not relative to the report")
        elif not (path.parent / unquote(target)).is_file():
            problems.append(f"image link {target!r} does not resolve from {path.parent}")
    return problems


class _Html(HTMLParser):
    def __init__(self):
        super().__init__()
        self.stack, self.errors, self.images, self.refs = [], [], [], []

    def handle_starttag(self, tag, attrs):
        for k, v in attrs:
            if k in ("src", "href") and v and not v.startswith("data:"):
                self.refs.append(v)
        if tag == "img":
            self.images.append(dict(attrs).get("src", ""))
        if tag not in VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag):
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> closes {self.stack[-1] if self.stack else 'nothing'}")
        else:
            self.stack.pop()


def html_problems(html_path, md_path):
    text = Path(html_path).read_text(encoding="utf-8")
    p = _Html()
    p.feed(text)
    p.close()
    problems = list(p.errors) + [f"unclosed <{t}>" for t in p.stack]
    problems += [f"external reference {r!r}" for r in p.refs]
    if re.search(r"(src|href)\s*=\s*[\"']?\s*(https?:|file:|//)", text, re.I):
        problems.append("http(s)/file reference in the HTML")
    n_md = len(re.findall(r"!\[[^\]]*\]\(", Path(md_path).read_text(encoding="utf-8")))
    embedded = [s for s in p.images if s.startswith("data:image/png;base64,") and len(s) > 1000]
    if len(embedded) != n_md or len(p.images) != n_md:
        problems.append(f"{n_md} figures in the Markdown, {len(embedded)} embedded of {len(p.images)} <img>")
    return problems


def assert_renders(report_md):
    report_md = Path(report_md)
    assert report_md.is_file()
    assert markdown_problems(report_md) == []
    html = report_md.with_suffix(".html")
    assert html.is_file(), "no report.html beside report.md"
    assert html_problems(html, report_md) == []
    return report_md.read_text(encoding="utf-8")


# --- the helpers ------------------------------------------------------------------------------------------------------

def test_pipes_in_cells_keep_the_table_shape():
    lines = md_table(("quantity", "value"), [("peak |S| (dB)", "6.1"), ("slews above (|L| >> 1 there)", "-"),
                                            ("already \\| escaped", "`a|b`")])
    assert [len(gfm_cells(ln)) for ln in lines] == [2, 2, 2, 2, 2]
    assert gfm_cells(lines[2]) == ["peak |S| (dB)", "6.1"]
    assert gfm_cells(lines[4]) == ["already | escaped", "`a|b`"]
    with pytest.raises(ValueError, match="3 cells"):
        md_table(("a", "b"), [(1, 2, 3)])


@settings(max_examples=200, deadline=None)
@given(st.lists(st.text(alphabet=st.sampled_from("ab |\\`*_-:\n"), max_size=12), min_size=1, max_size=6))
def test_any_cell_text_stays_one_cell(cells):
    """Whatever the text (pipes, backslashes, backticks, line breaks), a row keeps its cell count, and
    the workbench's own reader gives back the text GFM would."""
    row = md_row(*cells)
    assert "\n" not in row
    assert len(gfm_cells(row)) == len(cells)
    assert split_table_row(row) == gfm_cells(row)
    for c, got in zip(cells, gfm_cells(row)):
        if "\\" not in c:
            assert got == " ".join(c.split()).strip() or got == re.sub(r"\s*\n+\s*", " ", c).strip()


def test_image_links_are_relative_to_the_report(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "out" / "calibrate").mkdir(parents=True)
    # the case: the figure named from the working directory, the report inside out/calibrate
    assert md_image("overview", "out/calibrate/overview.png", "out/calibrate/report.md") == "![overview](overview.png)"
    assert md_image("x", tmp_path / "figs" / "a b.png", tmp_path / "out" / "r.md") == "![x](../figs/a%20b.png)"


@pytest.mark.parametrize("key, value, expected", [
    ("oscillation_command_v", 0.0123, ("oscillation command", "12.3", "mV")),
    ("settling_s", 0.0091, ("settling", "9.1", "ms")),
    ("drift_m", -2.3e-9, ("drift", "-2.3", "nm")),
    ("peak_current_source_a", 0.002, ("peak current source", "2", "mA")),
    ("corner_hz", 1250.0, ("corner", "1.25", "kHz")),
    ("time_at_limit_fraction", 0.25, ("time at limit", "25", "%")),
    ("phase_deg", 181.5, ("phase", "181.5", "deg")),
    ("overshoot_percent", float("nan"), ("overshoot", "n/a", "%")),
    ("count", 7, ("count", "7", "")),
    ("stiffness_n_per_m", 3.0e7, ("stiffness", "30000000", "N/m")),
    ("gain_per_s", 2.0, ("gain", "2", "1/s")),
])
def test_readable_quantity(key, value, expected):
    assert readable_quantity(key, value) == expected


def test_unwrapped_phase_and_db_of_a_delayed_integrator():
    """L = e^{-j w tau} / (j w): phase -90 - 360 f tau deg exactly, drawn through -180 and -540 without
    folding; |L| in dB is -20 log10(w); a NaN gap stays a gap and the sheet is kept across it."""
    import numpy as np
    from workbench.report.design_figures import db, unwrapped_deg
    f = np.geomspace(1.0, 5000.0, 400)
    tau = 400e-6                                  # 2 turns of extra phase by 5 kHz
    w = 2 * np.pi * f
    loop = np.exp(-1j * w * tau) / (1j * w)
    ph = unwrapped_deg(loop)
    np.testing.assert_allclose(ph, -90 - 360 * f * tau, atol=1e-9)
    np.testing.assert_allclose(db(loop), -20 * np.log10(w), atol=1e-9)
    gap = loop.copy()
    gap[150:160] = np.nan
    ph_gap = unwrapped_deg(gap)
    assert np.isnan(ph_gap[150:160]).all() and np.isnan(db(gap)[150:160]).all()
    np.testing.assert_allclose(np.delete(ph_gap, range(150, 160)), np.delete(ph, range(150, 160)), atol=1e-9)
    assert np.isnan(db(np.zeros(3))).all()


def test_html_is_self_contained_and_well_formed(tmp_path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    fig.savefig(tmp_path / "f.png")
    plt.close(fig)
    md = tmp_path / "report.md"
    md.write_text("# T `x|y`\n\nA <b>tag</b> & **bold** _it_ [link](https://example.com).\n\n"
                  + "\n".join(md_table(("a", "b"), [("|S|", "1 < 2")])) + "\n\n![f](f.png)\n\n- one\n- two\n\n"
                  "```\ncode | <x>\n```\n")
    html = write_html_report(md)
    assert html_problems(html, md) == []
    text = html.read_text()
    assert "<td>|S|</td>" in text and "&lt;b&gt;tag" in text and "<strong>bold</strong>" in text
    assert "example.com" not in text and "<li>two</li>" in text and "<title>T x|y</title>" in text
    assert "<title>Design study sn637_servo</title>" in markdown_to_html("# Design study `sn637_servo`\n")
    # a missing figure is named in the page, never linked
    md.write_text("![gone](gone.png)\n")
    assert "gone.png not found" in markdown_to_html(md.read_text(), tmp_path)
    assert "src=" not in markdown_to_html(md.read_text(), tmp_path)


# --- every report the commands write ----------------------------------------------------------------------------------

def test_verify_report_renders(tmp_path, monkeypatch):
    from workbench.cli import main
    monkeypatch.chdir(tmp_path)
    argv = ["verify", str(PLANTS / "p888_51_sn637_creep.toml"), "--controller",
            str(ROOT / "controllers" / "sn637_loopshape.json"), "--scenario", "small_step", "--out", "out/verify",
            "--json", "out/verify/v.json"]
    assert main(argv) == 0
    text = assert_renders(tmp_path / "out" / "verify" / "report.md")
    assert "small_step.png" in text and " SI |" not in text


def test_calibrate_report_renders(sn637, tmp_path, monkeypatch):
    from workbench.calibrate.protocol import calibration_protocol
    from workbench.calibrate.synthetic import plant_with_effect, simulate_record, write_record
    from workbench.cli import main
    monkeypatch.chdir(tmp_path)
    t, v = calibration_protocol(sine_cycles=2, stairs_v=(50.0, 20.0), chirp_s=0.5)
    plant, _ = plant_with_effect(sn637, "leakage", 3)
    write_record(tmp_path / "rec.csv", simulate_record(plant, t, v, seed=3), {"serial": "SN637"})
    assert main(["calibrate", "rec.csv", "--plant", str(PLANTS / "p888_51_sn637.toml"), "--out", "out/calibrate",
                 "--json", "out/calibrate/r.json"]) == 0
    text = assert_renders(tmp_path / "out" / "calibrate" / "report.md")
    assert "](out/calibrate/" not in text
    assert len(json.loads((tmp_path / "out" / "calibrate" / "r.json").read_text())["figures"]) == text.count("![")


def test_selfsense_report_renders(tmp_path, monkeypatch):
    from ..conftest import selfsense_main
    monkeypatch.chdir(tmp_path)
    assert selfsense_main([str(PLANTS / "p888_51_sn637.toml"), "--duration", "150s", "--no-loop", "--out", "out/ss",
                           "--json", "out/ss/s.json"]) == 0
    assert_renders(tmp_path / "out" / "ss" / "report.md")


@pytest.mark.slow
@pytest.mark.skipif(not FULL, reason="the reduced study already runs end to end in tests/study; WORKBENCH_FULL=1 "
                                     "renders its report here too")
def test_study_report_renders(tmp_path, monkeypatch):
    from workbench.cli import main
    text = (ROOT / "studies" / "sn637_servo.toml").read_text().replace('"../plants/', f'"{ROOT}/plants/')
    text = re.sub(r"amplitudes_v = \[.*?\]", "amplitudes_v = [0.1, 3.0]", text)
    text = re.sub(r"freq_points = \d+", "freq_points = 36", text)
    text = re.sub(r'serials = \[.*?\]', f'serials = ["{ROOT}/plants/p888_51_sn618.toml"]', text)
    text = re.sub(r"integral_ratios = \[.*?\]", "integral_ratios = [0.1, 0.25]", text)
    (tmp_path / "study.toml").write_text(text.replace("fc_min_hz = 50.0", "fc_min_hz = 80.0"))
    monkeypatch.chdir(tmp_path)
    assert main(["study", "study.toml", "--out", "out/study"]) == 0
    md = assert_renders(tmp_path / "out" / "study" / "report.md")
    assert md.count("![") == 4

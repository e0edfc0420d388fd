"""benchmarks/common.py's report writer: a script replaces only its own section, so the others and the decision
log's figures written by hand stay."""

from __future__ import annotations

from benchmarks import common

REPORT = """# A report

Its header, by hand.

<!-- section: speed -->
## Speed

old speed table

<!-- section: decision-log -->
## From the decision log

D1: 1.02x
"""


def test_a_section_is_replaced_in_place_and_the_rest_kept(tmp_path):
    report = tmp_path / "report.md"
    report.write_text(REPORT)
    common.write_section("speed", "## Speed\n\nnew speed table\n", report)
    assert report.read_text() == REPORT.replace("old speed table", "new speed table")
    common.write_section("speed", "## Speed\n\nnewer\n", report)  # again: still one section, in its place
    assert report.read_text() == REPORT.replace("old speed table", "newer")


def test_a_new_section_is_appended_and_a_new_report_starts_with_its_header(tmp_path):
    report = tmp_path / "report.md"
    report.write_text(REPORT)
    common.write_section("memory", "## Memory\n\n1 GiB", report)
    assert report.read_text() == REPORT + "\n<!-- section: memory -->\n## Memory\n\n1 GiB\n"
    fresh = tmp_path / "new" / "fresh.md"
    common.write_section("speed", "## Speed", fresh, header="# Fresh\n")
    assert fresh.read_text() == "# Fresh\n\n<!-- section: speed -->\n## Speed\n"
    bare = tmp_path / "bare.md"
    common.write_section("speed", "# Speed", bare)
    assert bare.read_text() == "<!-- section: speed -->\n# Speed\n"


def test_a_marker_quoted_inside_a_line_is_not_a_section(tmp_path):
    report = tmp_path / "report.md"
    text = "# R\n\nSections start at `<!-- section: speed -->` lines.\n\n<!-- section: speed -->\nold\n"
    report.write_text(text)
    common.write_section("speed", "new", report)
    assert report.read_text() == text.replace("old", "new")

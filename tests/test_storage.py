"""rba.core.fileio's reports: a regenerated Markdown report keeps the notes written by hand below its ``NOTES`` line."""

from __future__ import annotations

import json

from rba.core.fileio import NOTES, save_markdown, save_report


def test_a_regenerated_report_keeps_the_notes_below_the_marker(tmp_path):
    path = tmp_path / "r.md"
    path.write_text(f"# old\n\n| a | 1 |\n\n{NOTES}\n\nRow a was measured again on 12-07 at abc123.\n")
    save_markdown(path, "# new\n\n| a | 2 |\n")
    text = path.read_text()
    assert text.startswith("# new\n\n| a | 2 |\n\n" + NOTES)  # the generated part replaced, the notes after it
    assert "| a | 1 |" not in text and text.endswith("Row a was measured again on 12-07 at abc123.\n")
    save_markdown(path, "# newer\n")  # again: the notes once, not twice
    assert path.read_text().count("measured again") == 1 and path.read_text().count(NOTES) == 1


def test_without_the_marker_the_report_is_replaced_whole(tmp_path):
    path = tmp_path / "r.md"
    path.write_text("# old\n\nA note without the marker.\n")
    save_markdown(path, "# new\n")
    assert path.read_text() == "# new\n"
    save_markdown(tmp_path / "fresh.md", "# first\n")  # no report before
    assert (tmp_path / "fresh.md").read_text() == "# first\n"


def test_a_report_whose_text_carries_the_marker_is_written_as_given(tmp_path):
    path = tmp_path / "r.md"
    path.write_text(f"# old\n\n{NOTES}\n\nold note\n")
    save_markdown(path, f"# new\n\n{NOTES}\n\nnew note\n")
    assert path.read_text() == f"# new\n\n{NOTES}\n\nnew note\n"


def test_save_report_writes_the_numbers_and_keeps_the_notes(tmp_path):
    (tmp_path / "bench.md").write_text(f"# before\n\n{NOTES}\n\nwhy it was run again\n")
    save_report(tmp_path / "bench", {"rows": [1]}, "# after\n")
    assert json.loads((tmp_path / "bench.json").read_text()) == {"rows": [1]}
    assert (tmp_path / "bench.md").read_text() == f"# after\n\n{NOTES}\n\nwhy it was run again\n"

"""benchmarks/paper_tables.py: merging (a re-measured row replaces the merged one; stale rows are refused), the
headline order, the teacher-kind tables, the state views, the labels link and ``--check``."""

import json

import pytest

from rba.core.fileio import NOTES, save_json
from rba.core.settings import REPO_ROOT
from rba.interact.evaluate import EvalResult
from tests.benchmark_scripts import load_benchmark

paper_tables = load_benchmark("paper_tables")


def _result(domain: str, precision: str, sr: float, user: str = "paper", method: str = "global") -> EvalResult:
    return EvalResult(domain, method, "onehot", precision, user, 0, sr, 2.0, 1.0, 3.0, [])


def _save(path, rows):
    save_json(path, paper_tables.json_rows([(r.domain, label, r) for label, r in rows]))


def test_merge_keeps_rows_this_run_did_not_measure(tmp_path):
    _save(tmp_path / "t.json", [("RBA-Global", _result(d, p, 0.5))
                                for d, p in (("walker", "normal"), ("walker", "high"), ("snake", "normal"))])
    fresh = [("walker", "RBA-Global", _result("walker", "normal", 1.0))]
    rows = paper_tables.merged(fresh, [tmp_path / "t.json"])
    got = {(d, r.precision): r.success_rate for d, _, r in rows}
    assert got == {("snake", "normal"): 0.5, ("walker", "normal"): 1.0, ("walker", "high"): 0.5}
    text = paper_tables.markdown(rows, ["snake", "walker"], ["normal"], 20, 0, 60.0)
    assert "| walker | RBA-Global | 1.00 / 2.00 (1.00) | 1.00 / 3.75 (1.47) |" in text


def test_stored_rows_carry_split_user_and_epsilon(tmp_path):
    _save(tmp_path / "t.json", [("RBA-Global", _result("walker", "high", 0.5))])
    row, = json.loads((tmp_path / "t.json").read_text())
    assert (row["split"], row["user"], row["epsilon"]) == ("test", "paper", "0.0238095 x (p1-p99 of serve proxies)")


def _stored(tmp_path, **change):
    row = {**paper_tables.json_rows([("walker", "RBA-Global", _result("walker", "normal", 0.5))])[0], **change}
    row = {k: v for k, v in row.items() if v is not None}
    save_json(tmp_path / "old.json", [row])
    return tmp_path / "old.json"


def test_merge_refuses_rows_without_split_measured_on_val_or_with_another_epsilon(tmp_path):
    with pytest.raises(paper_tables.StaleRowError, match="walker RBA-Global normal paper has no split"):
        paper_tables.merged([], [_stored(tmp_path, split=None)])
    with pytest.raises(paper_tables.StaleRowError, match="measured on split 'val'; the tables report 'test' only"):
        paper_tables.merged([], [_stored(tmp_path, split="val")])
    with pytest.raises(paper_tables.StaleRowError, match=r"measured with ε '0\.2 x range'"):
        paper_tables.merged([], [_stored(tmp_path, epsilon="0.2 x range")])
    # a row with its split but stored before rows carried ε: the robust ε came first, so it is the current one
    rows = paper_tables.merged([], [_stored(tmp_path, epsilon=None)])
    assert [(d, r.split) for d, _, r in rows] == [("walker", "test")]


def test_main_refuses_a_stale_merge_before_measuring(tmp_path, capsys):
    old = [{k: v for k, v in row.items() if k != "split"}
           for row in paper_tables.json_rows([("walker", "RBA-Global", _result("walker", "high", 0.5))])]
    save_json(tmp_path / "old.json", old)
    with pytest.raises(SystemExit) as exc:
        paper_tables.main(["--report-only", "--merge", str(tmp_path / "old.json"), "--out", str(tmp_path / "t.md")])
    assert exc.value.code == 2
    assert "has no split (measured before the val/test split" in capsys.readouterr().err
    assert not (tmp_path / "t.md").exists()


def test_report_only_combines_parallel_runs_later_file_wins(tmp_path):
    _save(tmp_path / "a.json", [("RBA-Global", _result("walker", "normal", 0.5)),
                                ("PbRL", _result("snake", "high", 0.25))])
    _save(tmp_path / "b.json", [("RBA-Global", _result("walker", "normal", 0.9))])
    out = tmp_path / "t.md"
    paper_tables.main(["--report-only", "--merge", str(tmp_path / "a.json"), str(tmp_path / "b.json"),
                       "--precisions", "high", "--out", str(out)])
    text = out.read_text()
    assert "| walker | RBA-Global | 0.90 / 2.00 (1.00) |" in text
    assert "| snake | PbRL | 0.25 / 2.00 (1.00) |" in text
    assert "0.50 /" not in text
    # high precision is the headline: the paper's Table 2 comes first; every precision with rows is shown
    assert text.index("## Table 2 — high precision (the headline)") < text.index("## Table 1 — normal precision")
    assert "from the `test` split" in text and "1st to 99th percentile" in text


def test_one_table_per_teacher_kind_beside_the_paper_tables(tmp_path):
    rows = [(d, label, _result(d, "normal", sr, user, method))
            for user, sr in (("mistake:0.1", 0.95), ("skip:0.2", 0.9))
            for d in ("walker", "snake") for label, method in (("RBA-Global", "global"), ("RBA-Local", "local"))]
    rows += [("walker", "RBA-Global", _result("walker", "normal", 1.0))]
    _save(tmp_path / "a.json", [(label, r) for _, label, r in rows])
    merged = paper_tables.merged([], [tmp_path / "a.json"])
    assert len(merged) == len(rows)  # the user is part of a row's identity
    text = paper_tables.markdown(merged, ["snake", "walker"], ["normal"], 20, 0, 60.0, ["mistake:0.1", "skip:0.2"])
    mistake = text.index("### User `mistake:0.1`")
    assert mistake < text.index("### User `skip:0.2`")
    assert "| domain | Random | RBA-Global | RBA-Local | Oracle |" in text[mistake:]
    assert "| walker | – | 0.95 / 2.00 (1.00) | 0.95 / 2.00 (1.00) | – |" in text[mistake:]
    main = text[:text.index("## Teacher kinds")]
    assert "User: `paper`" in main and "| walker | RBA-Global | 1.00 / 2.00 (1.00) |" in main
    assert "0.95" not in main and "--users mistake:0.1 skip:0.2" in text


def test_users_option_names_the_valid_kinds(capsys):
    with pytest.raises(SystemExit) as exc:
        paper_tables.main(["--users", "grumpy", "--report-only"])
    assert exc.value.code == 2
    assert "unknown user kind 'grumpy'; valid: paper, mistake, skip" in capsys.readouterr().err


def test_teacher_kinds_are_measured_for_the_global_and_local_rows_of_the_paper_domains():
    users = [paper_tables.parse_user("skip")]
    assert paper_tables._jobs("walker", "RBA-Local", ["high"], ["RBA-Local"], users) == \
           [("paper", "high"), ("skip:0.2", "normal")]
    assert paper_tables._jobs("walker", "PbRL", ["high"], ["PbRL"], users) == [("paper", "high")]
    assert paper_tables._jobs("walker_raw", "RBA-Global", ["high"], ["RBA-Global"], users) == [("paper", "high")]
    assert paper_tables._jobs("snake", "RBA-Global", ["normal"], ["RBA-Global"], users) == \
           [("paper", "normal"), ("skip:0.2", "normal")]
    assert paper_tables._jobs("snake", "RBA-Local", ["normal"], ["RBA-Global"], users) == []  # --methods limits kinds


def test_raw_state_views_sit_beside_the_hand_made_view_only_where_measured():
    rows = [("walker", "RBA-Global", _result("walker", "high", 0.9)),
            ("walker_raw", "RBA-Global", _result("walker_raw", "high", 0.6)),
            ("snake", "RBA-Global", _result("snake", "high", 0.8)),
            ("manipulator_raw", "RBA-Local", _result("manipulator_raw", "high", 0.3, method="local"))]
    text = paper_tables.markdown(rows, ["walker", "walker_raw"], ["high"], 20, 0, 1.0)
    views = text[text.index("## State views"):]
    assert "| walker | RBA-Global | high | 0.90 / 2.00 (1.00) | 0.60 / 2.00 (1.00) |" in views
    assert "| manipulator | RBA-Local | high | – | 0.30 / 2.00 (1.00) |" in views
    assert "| snake |" not in views
    assert "| walker_raw | RBA-Global | 0.60 / 2.00 (1.00) | 0.70 / 7.29 (2.63) |" in text  # the paper's walker
    assert "## State views" not in paper_tables.markdown(rows[:1], ["walker"], ["high"], 20, 0, 1.0)


def test_labels_section_links_the_label_noise_report_when_it_exists(tmp_path):
    rows = [("walker", "RBA-Global", _result("walker", "high", 0.9))]
    out, report = tmp_path / "results" / "paper_tables.md", tmp_path / "results" / "label_noise.md"
    assert "## Labels" not in paper_tables.markdown(rows, ["walker"], ["high"], 20, 0, 1.0, out=out,
                                                    label_report=report)
    report.parent.mkdir()
    report.write_text("# label noise\n")
    text = paper_tables.markdown(rows, ["walker"], ["high"], 20, 0, 1.0, out=out, label_report=report)
    assert "## Labels" in text and "[label_noise.md](label_noise.md)" in text


def test_report_only_without_merge_says_what_is_missing(capsys):
    with pytest.raises(SystemExit):
        paper_tables.main(["--report-only"])
    assert "--report-only needs --merge" in capsys.readouterr().err


def test_check_says_which_rows_differ_from_the_report(tmp_path):
    _save(tmp_path / "t.json", [("RBA-Global", _result("walker", "normal", 1.0)),
                                ("RBA-Global", _result("walker", "high", 0.9)),
                                ("RBA-Global", _result("walker", "normal", 0.7, "skip:0.2"))])
    rows = [("walker", "RBA-Global", _result("walker", "normal", 1.0)),
            ("walker", "RBA-Global", _result("walker", "high", 0.85)),
            ("walker", "RBA-Global", _result("walker", "normal", 0.7, "skip:0.2")),
            ("snake", "PbRL", _result("snake", "high", 0.5))]
    text, same = paper_tables.check(rows, tmp_path / "t.json")
    assert not same
    assert "| walker | RBA-Global | normal | paper | 1.00 / 2.00 (1.00) | 1.00 / 2.00 (1.00) | yes |" in text
    assert "| walker | RBA-Global | high | paper | 0.90 / 2.00 (1.00) | 0.85 / 2.00 (1.00) | NO |" in text
    assert "| walker | RBA-Global | normal | skip:0.2 | 0.70 / 2.00 (1.00) | 0.70 / 2.00 (1.00) | yes |" in text
    assert "| snake | PbRL | high | paper | missing |" in text
    assert paper_tables.check(rows[:1], tmp_path / "t.json")[1]
    assert paper_tables.check(rows[2:3], tmp_path / "t.json")[1]


def test_the_generating_row_sits_below_rba_global_and_generates(gap_roots, monkeypatch):
    monkeypatch.setenv("RBA_DATA_DIR", str(gap_roots[0]))
    monkeypatch.setenv("RBA_MODELS_DIR", str(gap_roots[1]))
    rows = paper_tables.run(["toy"], ["normal"], 2, 0, ["RBA-Global", "RBA-Global+gen"])
    assert [(label, r.generate) for _, label, r in rows] == [("RBA-Global", False), ("RBA-Global+gen", True)]
    # what generating cost is reported (these targets are near serve clips: whether it searched is test_generate's)
    assert rows[0][2].generation is None and set(rows[1][2].generation) >= {"searches", "simulations", "shown"}
    text = paper_tables.markdown(rows, ["toy"], ["normal"], 2, 0, 1.0)
    assert text.index("| toy | RBA-Global |") < text.index("| toy | RBA-Global+gen |")


TABLE_DOMAINS = {"walker": "walker", "manipulator": "manipulator", "snake": "snake", "lane change": "lane_change"}


def _readme_tables() -> list[tuple[str, list[str], list[list[str]]]]:
    """(precision, column domains, rows of cells) of each table in the paper comparison of docs/results.md."""
    section = (REPO_ROOT / "docs" / "results.md").read_text().split("## Paper comparison", 1)[1].split("\n## ", 1)[0]
    tables, precision = [], None
    for block in section.split("\n\n"):
        first = block.strip().splitlines()[0] if block.strip() else ""
        if first.startswith(("Normal precision", "High precision")):
            precision = "normal" if first.startswith("Normal") else "high"
        elif first.startswith("| method |"):
            lines = [[c.strip() for c in line.strip().strip("|").split("|")] for line in block.strip().splitlines()]
            tables.append((precision, [TABLE_DOMAINS[c] for c in lines[0][1:]], lines[2:]))
    return tables


NOT_MEASURED = "not measured"


def test_readme_results_say_what_the_report_says():
    """Every SR / AF in docs/results.md's paper comparison is the report's row, and every paper number the paper's: a
    re-measured report with the document left behind fails here."""
    report = {(r["domain"], r["label"], r["precision"]): r
              for r in json.loads((REPO_ROOT / "benchmarks/results/paper_tables.json").read_text())
              if r["user"] == paper_tables.PAPER_USER}
    tables = _readme_tables()
    assert [p for p, *_ in tables] == ["normal", "high"]
    checked = 0
    for precision, domains, rows in tables:
        for cells in rows:
            label = cells[0].split(" (")[0]
            for domain, cell in zip(domains, cells[1:], strict=True):
                ours, _, paper = cell.partition(" (")
                if ours == NOT_MEASURED:  # a row the report lacks may say so, never a number of its own
                    assert (domain, label, precision) not in report, (domain, label, precision)
                    continue
                row = report[(domain, label, precision)]
                assert ours == paper_tables._cell(row["success_rate"], row["avg_feedback"], 0.0).split(" (")[0], \
                    (domain, label, precision)
                if paper:
                    sr, af, _ = paper_tables.PAPER[precision][domain][paper_tables.PAPER_LABELS.index(label)]
                    want = f"{sr:.2f} / " + ("–" if af is None else f"{af:.2f}")
                    assert paper.rstrip(")").removeprefix("paper ") == want, (domain, label, precision)
                checked += 1
    assert checked >= 30


def test_the_report_written_again_keeps_its_notes(tmp_path):
    """The shipped report regenerated from its own rows: the generated part as before, the notes below ``NOTES``
    kept word for word (they say when and why rows were measured again)."""
    shipped = (REPO_ROOT / "benchmarks" / "results" / "paper_tables.md").read_text()
    out = tmp_path / "paper_tables.md"
    out.write_text(shipped)
    paper_tables.main(["--report-only", "--merge", str(REPO_ROOT / "benchmarks" / "results" / "paper_tables.json"),
                       "--out", str(out)])
    text = out.read_text()
    assert NOTES in shipped and text[text.index(NOTES):] == shipped[shipped.index(NOTES):]
    assert "## Table 2 — high precision (the headline)" in text[:text.index(NOTES)]

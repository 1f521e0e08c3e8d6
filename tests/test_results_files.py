"""What ``benchmarks/results/`` holds is what the benchmark scripts write, and what the reports cite exists.

(a) Every script ``benchmarks/*.py`` that writes into ``benchmarks/results/`` declares its files in a module-level
``OUTPUTS`` tuple of names or glob patterns (read here with ``ast``, without importing the script). Every file in
``benchmarks/results/`` must match a pattern of some script; every pattern must match a file; and the script must
name the file's stem outside the declaration too (its default ``--out``, its documented command or the name it
writes), so that a declaration cannot stand in for a script that writes something else.

(b) The prose (``README.md``, ``docs/**/*.md``, ``benchmarks/results/*.md``) may name a commit only if it exists
(``git cat-file -e``), and a ``path/file.py:LINE`` reference only if the file exists and has that line. A commit is
a 7–40 character hex word with a digit and a letter, in a paragraph that says "commit" (other hex words, such as a
library's content hash in a table, are not commits).
"""

import ast
import fnmatch
import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
BENCHMARKS = REPO / "benchmarks"
RESULTS = BENCHMARKS / "results"


def declared_outputs() -> dict[str, tuple[tuple[str, ...], str]]:
    """script name -> (its OUTPUTS patterns, its source without the OUTPUTS assignment)."""
    found = {}
    for script in sorted(BENCHMARKS.glob("*.py")):
        source = script.read_text()
        for node in ast.parse(source).body:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(
                node, ast.AnnAssign) else []
            if any(isinstance(t, ast.Name) and t.id == "OUTPUTS" for t in targets):
                patterns = ast.literal_eval(node.value)
                assert isinstance(patterns, tuple) and all(isinstance(p, str) for p in patterns), script.name
                rest = source.replace(ast.get_source_segment(source, node), "")
                found[script.name] = (patterns, rest)
    return found


def result_files() -> list[str]:
    return sorted(str(p.relative_to(RESULTS)) for p in RESULTS.rglob("*") if p.is_file())


def test_every_results_file_is_written_by_a_benchmark_script():
    outputs = declared_outputs()
    assert outputs, "no benchmarks/*.py declares OUTPUTS"
    orphans = [f for f in result_files()
               if not any(fnmatch.fnmatchcase(f, p) for patterns, _ in outputs.values() for p in patterns)]
    assert not orphans, (f"{orphans}: no benchmarks/*.py declares these in OUTPUTS; a report no script writes "
                         "belongs in a decision record (docs/decisions/) or nowhere")


def test_every_declared_output_exists_and_its_script_names_it():
    files = result_files()
    for script, (patterns, rest) in declared_outputs().items():
        for pattern in patterns:
            assert "/" not in pattern, f"{script}: {pattern}: results are one flat folder"
            assert any(fnmatch.fnmatchcase(f, pattern) for f in files), \
                f"{script} declares {pattern}, which is not in benchmarks/results/"
            stem = re.split(r"[*.]", pattern, maxsplit=1)[0]
            assert stem and stem in rest, f"{script} declares {pattern} but never names {stem!r} where it writes"


def prose_files() -> list[Path]:
    return [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md")), *sorted(RESULTS.glob("*.md"))]


HEX = re.compile(r"(?<![\w.\-/])[0-9a-f]{7,40}(?![\w.])")
LINE_REF = re.compile(r"(?<![\w/.\-])((?:[\w.\-]+/)*[\w.\-]+\.py):(\d+)\b")


def _git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "-C", str(REPO), *args], capture_output=True, text=True)


@pytest.fixture(scope="module")
def full_history():
    """The repository's whole history: a shallow clone is deepened first, since a commit beyond its boundary would
    look missing. Git is required (CI has it); a shallow clone that cannot be deepened fails with the fix."""
    shallow = _git("rev-parse", "--is-shallow-repository")
    assert shallow.returncode == 0, f"git is needed to check the commits the reports name: {shallow.stderr.strip()}"
    if shallow.stdout.strip() == "true":
        deepen = _git("fetch", "--quiet", "--unshallow")
        assert deepen.returncode == 0, ("this clone is shallow and could not be deepened "
                                        f"({deepen.stderr.strip()}): run `git fetch --unshallow`")


def named_commits(text: str) -> set[str]:
    shas = set()
    for paragraph in re.split(r"\n\s*\n", text):
        if "commit" in paragraph.lower():
            shas |= {h for h in HEX.findall(paragraph) if re.search(r"\d", h) and re.search(r"[a-f]", h)}
    return shas


def test_named_commits_exist(full_history):
    missing = []
    for path in prose_files():
        for sha in sorted(named_commits(path.read_text())):
            if _git("cat-file", "-e", f"{sha}^{{commit}}").returncode != 0:
                missing.append(f"{path.relative_to(REPO)}: {sha}")
    assert not missing, f"commits named in the prose that this repository does not have: {missing}"


def test_line_references_point_at_existing_lines():
    broken = []
    for path in prose_files():
        for file, line in LINE_REF.findall(path.read_text()):
            target = REPO / file
            if not target.is_file():
                broken.append(f"{path.relative_to(REPO)}: {file}:{line} (no such file)")
            elif int(line) > len(target.read_text().splitlines()):
                broken.append(f"{path.relative_to(REPO)}: {file}:{line} (the file has fewer lines)")
    assert not broken, f"line references that point nowhere (re-run the script that wrote the report): {broken}"


def test_the_rules_see_what_they_should():
    """The patterns on examples: a commit only where the paragraph says so, no decimals or dates; line references."""
    assert named_commits("at commit 6d43436, then\n\n| `5d15e3ee5e97` |") == {"6d43436"}
    assert named_commits("commit: ε = 0.0238095 x, 20260930, g2a571b6068, abcdefab") == set()
    assert named_commits("commits 6d43436–6a7ab85") == {"6d43436", "6a7ab85"}
    assert LINE_REF.findall("see `rba/cli.py:12` and server/main.py:3.") == [("rba/cli.py", "12"),
                                                                           ("server/main.py", "3")]

"""docs/model.md is the model's documentation in the repository: it exists, and every section
that anything in the repository cites (``docs/model.md §N``, ``model §N``, or ``§N`` inside
the page itself) is a heading of it. Citations of the old, unpublished document ("spec 9.1",
"spec section 8") are gone."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / 'docs' / 'model.md'

# '§9.1', '§ 5' ... after 'docs/model.md ' or 'model ' (or anywhere in docs/model.md itself)
CITE = re.compile(r'(?:docs/model\.md|\bmodel),? ?((?:§ ?\d+(?:\.\d+)?(?:(?:,| and|–|-) ?)?)+)')
SECTION = re.compile(r'§ ?(\d+(?:\.\d+)?)')
OLD = re.compile(r"\bspec(?:'s)? (?:section |§ ?)?\d|\bspec §|shared[/]spec")


def _sections() -> set[str]:
    heads = re.findall(r'^#{2,4} (\d+(?:\.\d+)?)\.? ', MODEL.read_text(), re.M)
    return set(heads)


def _repo_files() -> list[Path]:
    out = subprocess.run(['git', 'ls-files', '--cached', '--others', '--exclude-standard'],
                         cwd=ROOT, capture_output=True, text=True, check=True).stdout
    files = []
    for name in out.splitlines():
        path = ROOT / name
        if path.is_file() and path.suffix in {'.py', '.md', '.yaml', '.txt', '.cfg', '.toml',
                                               '.xml', '.sh', ''}:
            files.append(path)
    return files


def _citations() -> dict[str, list[str]]:
    """section -> where it is cited."""
    cited: dict[str, list[str]] = {}
    for path in _repo_files():
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue
        rel = str(path.relative_to(ROOT))
        if path.resolve() == Path(__file__).resolve():
            continue          # this file's examples
        if path == MODEL:
            spans = [m.group(0) for m in SECTION.finditer(text)]
        else:
            spans = [m.group(1) for m in CITE.finditer(text)]
        for span in spans:
            for num in SECTION.findall(span):
                cited.setdefault(num, []).append(rel)
    return cited


def test_model_doc_has_numbered_sections_one_to_ten():
    sections = _sections()
    assert {str(n) for n in range(1, 11)} <= sections
    assert {f'9.{n}' for n in range(1, 10)} <= sections      # every resolution
    assert {'5.4', '5.5', '5.6'} <= sections                 # ABM, FFT, SOE history


def test_every_cited_section_exists():
    cited = _citations()
    # the code and README do cite the page (so this test checks something)
    assert {'3', '5.4', '5.6', '6', '7', '8', '9.1', '9.7', '9.8', '9.9'} <= set(cited)
    missing = {num: where for num, where in cited.items() if num not in _sections()}
    assert not missing, f'cited sections docs/model.md lacks: {missing}'


def test_no_citation_of_the_old_document_remains():
    old = []
    for path in _repo_files():
        try:
            lines = path.read_text().splitlines()
        except UnicodeDecodeError:
            continue
        old += [f'{path.relative_to(ROOT)}:{i}: {line.strip()}'
                for i, line in enumerate(lines, 1) if OLD.search(line)]
    this = Path(__file__).resolve().relative_to(ROOT)
    old = [o for o in old if not o.startswith(f'{this}:')]
    assert not old, '\n'.join(old)


def test_citation_pattern_finds_a_missing_section(tmp_path):
    # the check would fail on a citation of a section the page lacks
    text = 'see docs/model.md §9.1, §12 and model §5.4'
    nums = [n for m in CITE.finditer(text) for n in SECTION.findall(m.group(1))]
    assert nums == ['9.1', '12', '5.4'] and '12' not in _sections()

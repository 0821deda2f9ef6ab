"""The documentation: a short README front page, its two commands, its generated benchmark
table, links that resolve (on GitHub and in the mkdocs site, which .ci/run builds with
``mkdocs build --strict``; no build here), and the commands, names, modules and extras the
pages and docstrings name, each of which exists (a few seconds: the names' check imports
the modules it names)."""
from __future__ import annotations

import dataclasses
import fnmatch
import importlib
import re
import shutil
import subprocess
import sys
import unicodedata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = ROOT / "docs"
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
from benchmarks import doc_blocks, readme_table  # noqa: E402

REPRODUCE = ("python3 -m venv .venv && .venv/bin/pip install -e . && "
             ".venv/bin/vdbejax reproduce --out out/paper")
TESTS = "bash .ci/run"
BENCHMARK = "bash .ci/run -m benchmark"

LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^(```|~~~).*?^\1[^\n]*$", re.S | re.M)
CODE_SPAN = re.compile(r"(`+)(?!`).*?(?<!`)\1(?!`)", re.S)
HEADING = re.compile(r"^#{1,6}\s+(.+?)\s*#*\s*$", re.M)


def _pages() -> list[Path]:
    return [README, *sorted(DOCS.rglob("*.md"))]


def _prose(text: str) -> str:
    """The text without fenced code blocks and code spans (no links live there)."""
    return CODE_SPAN.sub("", FENCE.sub("", text))


def _links(page: Path) -> list[str]:
    return [t for t in LINK.findall(_prose(page.read_text(encoding="utf-8")))
            if not re.match(r"^[a-z][a-z0-9+.-]*:", t)]


def _slug(heading: str) -> str:
    """A heading's anchor as GitHub and mkdocs (Python-Markdown's toc) both make it, for
    ASCII headings: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading).replace("`", "")
    text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode()
    return re.sub(r"[\s]+", "-", re.sub(r"[^\w\s-]", "", text).strip().lower())


def _anchors(page: Path) -> set[str]:
    return {_slug(h) for h in HEADING.findall(FENCE.sub("", page.read_text(encoding="utf-8")))}


# ------------------------------------------------------------------ the front page
def test_readme_is_a_front_page_of_at_most_200_lines():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 200, f"README.md has {len(lines)} lines (at most 200)"


def test_readme_shows_the_two_commands_verbatim():
    text = README.read_text(encoding="utf-8")
    assert f"```bash\n{REPRODUCE}\n```" in text
    assert f"```bash\n{TESTS}\n```" in text
    assert f"`{BENCHMARK}` runs that one alone" in text
    # ... and the documentation site's home page says the same.
    home = (DOCS / "index.md").read_text(encoding="utf-8")
    assert REPRODUCE in home and TESTS in home and BENCHMARK in home


def test_readme_benchmark_table_is_generated_from_results():
    text = README.read_text(encoding="utf-8")
    assert text.count(readme_table.START) == 1 and text.count(readme_table.END) == 1
    assert readme_table.current_block(text) == readme_table.block(), (
        "README.md's benchmark table differs from benchmarks/RESULTS.md: "
        "run `python -m benchmarks.readme_table`")


def test_readme_table_generator_takes_the_headline_rows(tmp_path):
    text = readme_table.headline(readme_table.RESULTS.read_text(encoding="utf-8"))
    rows = [line.split("|")[1].strip() for line in text.splitlines()
            if line.startswith("| ") and not line.startswith("| ---")]
    assert rows[0] == "peer" and rows[1].startswith("vdbejax ") and "warm" in rows[1]
    assert any(r.startswith("numba-1t (warm") for r in rows)
    assert all("cold" not in r and "lockstep" not in r for r in rows[1:])
    assert "Ratios (" in text and "numba-1t / vdbejax" in text
    # ... then the par table: a call repeated in one process, with its date and commit.
    assert "`python -m benchmarks.par` (" in text and "; commit `" in text
    assert any(r.startswith("`run_grid` again in one process") for r in rows)
    # main() rewrites only the block of the file it is given, and --check agrees.
    readme = tmp_path / "README.md"
    readme.write_text(f"before\n{readme_table.START}\nstale\n{readme_table.END}\nafter\n")
    assert readme_table.main(["--readme", str(readme), "--check"]) == 1
    assert readme_table.main(["--readme", str(readme)]) == 0
    new = readme.read_text()
    assert new.startswith("before\n") and new.endswith("\nafter\n")
    assert readme_table.current_block(new) == readme_table.block()
    assert readme_table.main(["--readme", str(readme), "--check"]) == 0
    with pytest.raises(ValueError, match="no '## Full paper grid' section"):
        readme_table.headline("# Benchmarks\n- Date: today.\n")


def test_the_tables_of_the_docs_are_copied_from_the_results_files():
    assert DOCS / "performance.md" in doc_blocks.pages()
    for page in doc_blocks.pages():
        text = page.read_text(encoding="utf-8")
        assert doc_blocks.render(text) == text, (
            f"{page.name}: a table differs from its results file: run"
            " `python -m benchmarks.doc_blocks`")


def test_doc_blocks_copy_the_named_table_and_refuse_what_is_missing(tmp_path):
    results = tmp_path / "R.md"
    results.write_text("# R\n- Date: today.\n\n## Speed of it\n\n| a |\n| --- |\n| 1 |\n\n"
                       "text\n\n| b |\n| --- |\n| 2 |\n\n## Other 2026\n\n| c |\n| --- |\n| 3 |\n")
    page = ("intro\n<!-- results: R.md | Speed -->\nstale\n<!-- results:end -->\n"
            "<!-- results: R.md | Speed | table 2 -->\n<!-- results:end -->\n"
            "<!-- results: R.md | Other -->\n<!-- results:end -->\nend\n")
    assert doc_blocks.render(page, tmp_path) == (
        "intro\n<!-- results: R.md | Speed -->\nFrom `R.md`, “Speed of it” (today):\n\n"
        "| a |\n| --- |\n| 1 |\n<!-- results:end -->\n"
        "<!-- results: R.md | Speed | table 2 -->\nFrom `R.md`, “Speed of it” (today):\n\n"
        "| b |\n| --- |\n| 2 |\n<!-- results:end -->\n"
        "<!-- results: R.md | Other -->\nFrom `R.md`, “Other 2026”:\n\n"
        "| c |\n| --- |\n| 3 |\n<!-- results:end -->\nend\n")
    # A section with its own date, commit and machine lines says those, not the file's.
    (tmp_path / "S.md").write_text("# S\n- Date: today.\n\n## Own\n\n- Date: 2026-01-02.\n"
                                   "- Commit: `abc1234`.\n- Machine: two cores.\n\n"
                                   "| d |\n| --- |\n| 4 |\n")
    assert doc_blocks.render("<!-- results: S.md | Own -->\n<!-- results:end -->\n",
                             tmp_path).splitlines()[1] == (
        "From `S.md`, “Own” (2026-01-02; commit `abc1234`; two cores):")
    with pytest.raises(ValueError, match="no section whose heading starts with 'Nope'"):
        doc_blocks.render("<!-- results: R.md | Nope -->\n<!-- results:end -->\n", tmp_path)
    with pytest.raises(ValueError, match="has 2 table"):
        doc_blocks.render("<!-- results: R.md | Speed | table 3 -->\n<!-- results:end -->\n",
                          tmp_path)
    with pytest.raises(ValueError, match="has no"):
        doc_blocks.render("<!-- results: R.md | Speed -->\n", tmp_path)


#: Words of the project's work log, not of its results: a page states what is true today.
WORK_LOG = re.compile(r"\b(?:sessions?|sittings?)\b|\bissues? #?\d+|\(issue\b", re.I)


def _current_pages() -> list[Path]:
    """The README, the docs pages and the results pages of benchmarks/ (not its archive)."""
    return [*_pages(), *sorted((ROOT / "benchmarks").glob("*.md"))]


def test_pages_state_results_not_the_work_log():
    """No page names a work session, a sitting or an issue number ("issue 46", "(issue
    21)"): results are stated with their date, commit, machine and command, and earlier
    runs live in benchmarks/archive/, which this check does not read."""
    found = [f"{page.relative_to(ROOT)}:{n}: {line.strip()[:100]}"
             for page in _current_pages()
             for n, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1)
             if WORK_LOG.search(line)]
    assert not found, "work-log words on a current page:\n" + "\n".join(found)
    assert WORK_LOG.search("measured in one sitting") and WORK_LOG.search("(issue 21)")
    assert WORK_LOG.search("Session 2026-12-06") and WORK_LOG.search("issues 22, 23")
    assert not WORK_LOG.search("a known issue; sessionless")
    # The scaling study's page names no commit: its result folder's meta.json does.
    prose = [line for line in (DOCS / "SCALING.md").read_text(encoding="utf-8").splitlines()
             if not line.startswith("|")]
    assert not [line for line in prose if re.search(r"`[0-9a-f]{7,40}`", line)]


def test_results_sections_state_date_commit_machine_and_command():
    """Each hand-written section of benchmarks/RESULTS.md (after its harness tables) opens
    with its date, commit, machine and command; the archive has an index of its files."""
    text = readme_table.RESULTS.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 300, "benchmarks/RESULTS.md: over 300 lines (archive/)"
    header = text[:text.index("\n## ")]
    for key in ("Date", "Commit", "Machine", "Command"):
        assert f"\n- {key}: " in header, f"RESULTS.md's header: no '- {key}:' line"
    # the peers' per-setting differences: the page beside it, from the same run
    agreement = (ROOT / "benchmarks" / "AGREEMENT.md").read_text(encoding="utf-8")
    assert "[`AGREEMENT.md`](AGREEMENT.md)" in text
    assert [line for line in agreement.splitlines() if line.startswith("- Date: ")] == [
        line for line in header.splitlines() if line.startswith("- Date: ")]
    hand = text[text.index("## Analysis"):].split("\n## ")[1:]
    assert len(hand) >= 5
    for section in hand:
        heading = section.splitlines()[0]
        keys = ("Date", "Machine", "Command") if heading.startswith("GPU") \
            else ("Date", "Commit", "Machine", "Command")
        for key in keys:
            assert f"\n- {key}: " in section, f"RESULTS.md, {heading!r}: no '- {key}:' line"
    archive = ROOT / "benchmarks" / "archive"
    index = (archive / "README.md").read_text(encoding="utf-8")
    assert {p.name for p in archive.glob("*.md")} - {"README.md"} == set(
        re.findall(r"\]\(([\w.-]+\.md)\)", index))


def test_readme_examples_are_in_the_documentation_site():
    """The README's Python examples also appear, verbatim, on the site's pages."""
    site = "\n".join(p.read_text(encoding="utf-8") for p in DOCS.glob("*.md"))
    blocks = re.findall(r"^```python\n(.*?)^```", README.read_text(encoding="utf-8"),
                        re.S | re.M)
    assert len(blocks) >= 2
    for block in blocks:
        assert block in site, block.splitlines()[0]


def test_every_docs_page_is_in_the_site_navigation():
    nav = set(re.findall(r":\s*(\S+\.md)\s*$", (ROOT / "mkdocs.yml").read_text(), re.M))
    pages = {p.relative_to(DOCS).as_posix() for p in DOCS.glob("*.md")}
    pages |= {p.relative_to(DOCS).as_posix() for p in (DOCS / "api").glob("*.md")}
    assert pages <= nav, f"not in mkdocs.yml's nav: {sorted(pages - nav)}"
    assert all((DOCS / page).exists() for page in nav), sorted(nav)


# ------------------------------------------------------------------------- links
def test_every_relative_link_and_image_resolves_to_a_kept_file():
    """Every relative link or image of README.md and docs/**/*.md names a file of the
    working tree that .gitignore does not ignore (so it is, or can be, tracked); a page
    of docs/ links only inside docs/ (the site's pages and files); a link to a heading of
    another page names one of its headings."""
    targets: dict[Path, list[str]] = {}
    problems = []
    for page in _pages():
        for link in _links(page):
            path, _, anchor = link.partition("#")
            target = (page.parent / path).resolve() if path else page
            where = f"{page.relative_to(ROOT)}: {link}"
            if not target.is_relative_to(ROOT):
                problems.append(f"{where} points outside the repository")
                continue
            if not target.exists():
                problems.append(f"{where} does not exist")
                continue
            if page != README and not target.is_relative_to(DOCS):
                problems.append(f"{where} leaves docs/ (not part of the site)")
            if anchor and target.suffix == ".md" and not target.is_relative_to(DOCS / "api") \
                    and anchor not in _anchors(target):
                problems.append(f"{where}: no heading '#{anchor}' there")
            if target.is_file():
                targets.setdefault(target, []).append(where)
    assert not problems, "\n".join(problems)
    git = shutil.which("git")
    if git is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout: the .gitignore check needs git")
    names = "\n".join(t.relative_to(ROOT).as_posix() for t in targets)
    done = subprocess.run([git, "check-ignore", "--no-index", "--stdin"], cwd=ROOT,
                          input=names, capture_output=True, text=True, timeout=60)
    assert done.returncode in (0, 1), done.stderr
    ignored = done.stdout.split()
    assert not ignored, "linked but ignored by .gitignore:\n" + "\n".join(
        where for name in ignored for where in targets[ROOT / name])


# ------------------------------------------------------------------ named commands
BENCHMARK_MODULE = re.compile(r"python3? -m benchmarks\.([A-Za-z_]\w*)")
TEST_FILE = re.compile(r"\btests/(test_\w+\.py)(?:::(\w+))?")


def _text_files() -> list[Path]:
    """The pages and the sources a reader follows: the package, benchmarks, examples."""
    return [*_pages(), *sorted((ROOT / "vdbejax").rglob("*.py")),
            *sorted((ROOT / "benchmarks").glob("*.py")),
            *sorted((ROOT / "examples").glob("*.py"))]


def test_every_named_benchmark_command_and_test_exists():
    """A ``python -m benchmarks.NAME`` or ``tests/test_X.py[::test_y]`` named by a page, a
    docstring or a comment is a module or test of the working tree (a renamed or deleted
    one leaves the reader a command that fails)."""
    problems = []
    for path in _text_files():
        text = path.read_text(encoding="utf-8")
        where = path.relative_to(ROOT)
        for name in set(BENCHMARK_MODULE.findall(text)):
            if not (ROOT / "benchmarks" / f"{name}.py").exists():
                problems.append(f"{where}: python -m benchmarks.{name}")
        for file, test in set(TEST_FILE.findall(text)):
            target = ROOT / "tests" / file
            if not target.exists():
                problems.append(f"{where}: tests/{file}")
            elif test and not re.search(rf"^def {test}\b", target.read_text(encoding="utf-8"),
                                        re.M):
                problems.append(f"{where}: tests/{file}::{test}")
    assert not problems, "named but missing:\n" + "\n".join(problems)


DOTTED_NAME = re.compile(r"(?<![\w./-])vdbejax(?:\.[A-Za-z_]\w*)+")


def _resolves(name: str) -> bool:
    """Whether ``vdbejax.a.b.c`` is a module of today, or an attribute or dataclass field
    below the longest importable module prefix of it."""
    parts = name.split(".")
    for cut in range(len(parts), 0, -1):
        module = ".".join(parts[:cut])
        try:
            obj = importlib.import_module(module)
        except ImportError:
            continue
        for attr in parts[cut:]:
            fields = {f.name for f in dataclasses.fields(obj)} \
                if isinstance(obj, type) and dataclasses.is_dataclass(obj) else set()
            if not hasattr(obj, attr) and attr not in fields:
                return False
            obj = getattr(obj, attr, None)
        return True
    return False


def test_every_dotted_name_of_the_docs_and_docstrings_exists():
    """``vdbejax.x.y`` named by a page, a docstring or a comment is a module or one of its
    attributes today (the CHANGELOG, which is history, is not read)."""
    missing = sorted({f"{path.relative_to(ROOT)}: {name}" for path in _text_files()
                      for name in DOTTED_NAME.findall(path.read_text(encoding="utf-8"))
                      if not _resolves(name)})
    assert not missing, "named but missing:\n" + "\n".join(missing)


#: The subpackages whose ``__all__`` is the public API, each with its page in docs/api/.
API_PAGES = {"methods": "vdbejax.methods", "envs": "vdbejax.envs", "engine": "vdbejax.engine",
             "runs": "vdbejax.runs", "results": "vdbejax.results", "studies": "vdbejax.studies",
             "paper": "vdbejax.paper"}
DIRECTIVE = re.compile(r"^::: *(\S+)\n((?:[ \t]+\S.*\n)*)", re.M)


def _directives(page: Path) -> dict[str, str]:
    """Each ``::: name`` directive of an API page, with its indented options."""
    return dict(DIRECTIVE.findall(page.read_text(encoding="utf-8")))


def _public(package: str, name: str) -> object:
    module = importlib.import_module(package)
    if hasattr(module, name):
        return getattr(module, name)
    return importlib.import_module(f"{package}.{name}")  # a submodule, imported when named


def test_the_api_pages_document_exactly_the_public_names():
    """Each page of docs/api/ renders its subpackage's docstring (no members) and one
    directive per name of the subpackage's ``__all__``: a name missing from the page, or a
    page rendering a name that ``__all__`` does not list, fails. The index renders only
    ``vdbejax``'s docstring, and each name ``vdbejax`` exports is documented on a page: in
    a subpackage's ``__all__``, or defined in a public module."""
    pages = {path.stem for path in (DOCS / "api").glob("*.md")}
    assert pages == {*API_PAGES, "index"}
    assert _directives(DOCS / "api" / "index.md") == {
        "vdbejax": "    options:\n      members: false\n"}
    documented = []
    for page, package in API_PAGES.items():
        directives = _directives(DOCS / "api" / f"{page}.md")
        assert directives.pop(package, None) == "    options:\n      members: false\n", \
            f"docs/api/{page}.md: render {package} with members: false first"
        public = importlib.import_module(package).__all__
        assert sorted(directives) == sorted(f"{package}.{name}" for name in public), \
            f"docs/api/{page}.md documents other names than {package}.__all__"
        documented += [_public(package, name) for name in public]
    import vdbejax

    modules = [m for m in documented if isinstance(m, type(vdbejax))]
    for name in vdbejax.__all__:
        value = getattr(vdbejax, name)
        assert any(value is d for d in documented) or any(
            vars(m).get(name) is value and getattr(value, "__module__", None) == m.__name__
            for m in modules), f"vdbejax.{name} is on no API page"


def test_a_page_with_a_name_not_in_all_fails_the_api_check(tmp_path, monkeypatch):
    page = tmp_path / "api" / "runs.md"
    page.parent.mkdir()
    page.write_text("# Runs\n\n::: vdbejax.runs\n    options:\n      members: false\n\n"
                    "::: vdbejax.runs.grid\n")
    assert _directives(page) == {"vdbejax.runs": "    options:\n      members: false\n",
                                 "vdbejax.runs.grid": ""}
    for other in (DOCS / "api").glob("*.md"):
        if other.name != "runs.md":
            (tmp_path / "api" / other.name).write_text(other.read_text(encoding="utf-8"))
    monkeypatch.setattr(sys.modules[__name__], "DOCS", tmp_path)
    with pytest.raises(AssertionError, match="other names than vdbejax.runs.__all__"):
        test_the_api_pages_document_exactly_the_public_names()


def test_every_module_of_the_package_is_on_the_architecture_map():
    """docs/architecture.md's map names every module of the package (by its file name, or
    a pattern such as ``ablation*.py``): a newcomer finds the file for an idea there."""
    page = (DOCS / "architecture.md").read_text(encoding="utf-8")
    named = set(re.findall(r"`(?:[\w/]*/)?([\w*]+\.py)`", page))
    modules = {path.name for path in (ROOT / "vdbejax").rglob("*.py")} - {"__init__.py"}
    unlisted = sorted(m for m in modules if not any(fnmatch.fnmatch(m, n) for n in named))
    assert not unlisted, f"not on docs/architecture.md's map: {unlisted}"


def test_every_optional_extra_is_on_the_install_page():
    """Each extra of pyproject.toml is named, as ``.[name]``, on the site's front page
    (and the README names every extra but ``rlberry``, whose peer has a venv of its own)."""
    import tomllib

    extras = set(tomllib.loads((ROOT / "pyproject.toml").read_text("utf-8"))
                 ["project"]["optional-dependencies"])
    index = (DOCS / "index.md").read_text("utf-8")
    readme = README.read_text("utf-8")
    assert {e for e in extras if f"`.[{e}]`" not in index} == set()
    assert {e for e in extras if f"`.[{e}]`" not in readme} == {"rlberry"}

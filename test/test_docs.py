"""The docs a newcomer reads agree with the code: the figures they count (packages, executables,
estimators, shipped scenarios and motors) are the code's, no page quotes a test count that goes stale,
every section of docs/results.md says when and by which command it was measured, and every link or
citation into it names a section it has."""
import ast
import re
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
RESULTS = DOCS / "results.md"
NUMBER_WORDS = {"one": 1, "two": 2, "three": 3, "four": 4, "five": 5, "six": 6, "seven": 7, "eight": 8, "nine": 9,
                "ten": 10, "eleven": 11, "twelve": 12}
DATE = re.compile(r"\b20\d\d-\d\d-\d\d\b")
COMMAND = re.compile(r"`(drive |python|pytest|bash |CI=true |git |\.venv/bin/)[^`]*`")


def pages():
    return [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]


def packages():
    return sorted(path.parent.name for path in (ROOT / "src").glob("*/package.xml"))


def console_scripts():
    """The executables the packages install (setup.py's console_scripts), `drive` aside."""
    names = []
    for setup in (ROOT / "src").glob("*/setup.py"):
        for node in ast.walk(ast.parse(setup.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and " = " in node.value:
                names.append(node.value.split(" = ")[0])
    return sorted(set(names) - {"drive"})


def sections(text):
    """(heading, body) of each Markdown heading of ``text``, the body up to the next heading."""
    parts = re.split(r"^(#{1,4} .*)$", text, flags=re.M)
    return list(zip(parts[1::2], parts[2::2]))


def slug(heading):
    """The anchor GitHub gives a heading."""
    text = heading.lstrip("#").strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def test_the_package_count_the_architecture_states_is_the_codes():
    first = (DOCS / "architecture.md").read_text().split()
    assert NUMBER_WORDS[first[first.index("packages") - 1].lower()] == len(packages()) == 6
    readme = (ROOT / "README.md").read_text()
    assert all(f"`src/{name}/`" in readme for name in packages())


def test_every_node_executable_is_named_in_the_readme_and_the_commands_page():
    executables = console_scripts()
    assert len(executables) == 5
    for page in (ROOT / "README.md", DOCS / "commands.md"):
        text = page.read_text()
        assert [name for name in executables if f"`{name}`" not in text and f"/{name} " not in text] == []


def test_every_estimator_is_described_and_every_estimator_the_docs_name_exists():
    from hf_estimator.registry import estimator_names
    names = set(estimator_names())
    described = (DOCS / "motors-and-control.md").read_text()
    assert [name for name in sorted(names) if f"`{name}`" not in described] == []


def test_every_shipped_scenario_and_motor_the_docs_name_exists():
    """A name in backticks that reads as a Wang or Szabó scenario or motor (`wang_…`, `szabo_…`, not a
    function of the code) is shipped."""
    from drive_common.config.scenario import scenario_names
    from drive_common.motor.motor_file import shipped_motor_names
    shipped = set(scenario_names()) | set(shipped_motor_names())
    assert {"wang_100rpm", "szabo_profile", "wang_spmsm", "szabo_ipmsm"} <= shipped
    named = {(page.name, name) for page in pages()
             for name in re.findall(r"`((?:wang|szabo)_[a-z0-9_]+)`", page.read_text())}
    code = "\n".join(path.read_text() for path in (ROOT / "src").rglob("*.py"))
    assert sorted((page, name) for page, name in named if name not in shipped and f"def {name}(" not in code) == []


def test_no_page_but_the_results_quotes_a_test_count():
    """A count of tests goes stale with the next test: the README and the docs say how to count them, the
    results page keeps dated counts."""
    stale = re.compile(r"\b\d+ (tests|passed|test modules)\b")
    quoted = [f"{page.name}: {match.group(0)}" for page in pages() if page != RESULTS
              for match in stale.finditer(page.read_text())]
    assert quoted == []


def test_every_results_section_says_when_and_by_which_command():
    text = RESULTS.read_text()
    assert "**The machine**" in sections(text)[0][1]
    undated = [heading for heading, body in sections(text)[1:]
               if not (DATE.search(heading + body) and COMMAND.search(heading + body))]
    assert undated == []
    assert not re.search(r"before issue \d+\)", "\n".join(heading for heading, _ in sections(text)))


def test_every_measured_section_of_the_other_pages_says_when_and_by_which_command():
    """A "Measured …" or "Results" section elsewhere in docs/ is dated with its command, or points to the
    results page."""
    undated = [f"{page.name}: {heading}" for page in sorted(DOCS.glob("*.md")) if page != RESULTS
               for heading, body in sections(page.read_text())
               if re.match(r"#+ (Measured|(\d+\. )?Results)\b", heading)
               and not (DATE.search(heading + body) and COMMAND.search(heading + body)) and "results.md" not in body]
    assert undated == []


def test_every_link_and_citation_into_the_results_names_one_of_its_sections():
    """`results.md#anchor` links and `results.md, "Title"` citations in docs/, README.md and src/."""
    text = RESULTS.read_text()
    headings = [heading.lstrip("#").strip() for heading, _ in sections(text)]
    anchors = {slug(heading) for heading in headings}
    titles = headings + re.findall(r"\*\*([^*]+)\*\*", text)
    cited = [*pages(), *(ROOT / "src").rglob("*.py")]
    broken = []
    for path in cited:
        source = re.sub(r"\s*\n\s*(#\s*)?", " ", path.read_text())
        broken += [f"{path.name}: #{anchor}" for anchor in re.findall(r"results\.md#([\w-]+)", source)
                   if anchor not in anchors]
        broken += [f"{path.name}: {title}" for title in re.findall(r"results\.md,? \"([^\"]+)\"", source)
                   if not any(known.startswith(title) for known in titles)]
    assert broken == []


def test_the_readme_stays_within_ten_kilobytes():
    assert len((ROOT / "README.md").read_bytes()) <= 10_000

"""One name per quantity (docs/glossary.md): no synonym the glossary refuses in the code, the shipped files
or the docs, and the glossary's code names exist in the code."""
import io
import re
import subprocess
import tokenize
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parent.parent
GLOSSARY = ROOT / "docs" / "glossary.md"
QUANTITY_COLUMNS = ("quantity", "symbol", "code name", "unit", "key where it differs", "refused")
SHIPPED_SUFFIXES = (".py", ".yaml", ".md", ".xml", ".cfg")


def tables(text):
    """Each Markdown table of ``text`` as (its header's cells, its rows' cells)."""
    found, rows = [], []
    for line in text.splitlines() + [""]:
        if line.startswith("|"):
            rows.append([cell.strip() for cell in re.split(r"(?<!\\)\|", line.strip())[1:-1]])
        elif rows:
            found.append((tuple(rows[0]), [row for row in rows[2:]]))
            rows = []
    return found


def names(cell):
    return re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", cell)


def quantities():
    return [dict(zip(QUANTITY_COLUMNS, row)) for header, rows in tables(GLOSSARY.read_text())
            if header == QUANTITY_COLUMNS for row in rows]


def checked_files():
    """Tracked files the glossary holds for: src/ (code, shipped motors and scenarios, package files), the
    shipped commissioning files, docs/ (the glossary itself aside) and the README."""
    listed = subprocess.run(["git", "ls-files", "src", "commissioning", "docs", "README.md"], cwd=ROOT,
                            capture_output=True, text=True, check=True).stdout.split()
    return [ROOT / path for path in listed if path.endswith(SHIPPED_SUFFIXES) and ROOT / path != GLOSSARY]


def python_names(path):
    """The identifiers of a Python file (names, not strings or comments)."""
    tokens = tokenize.generate_tokens(io.StringIO(path.read_text()).readline)
    return {token.string for token in tokens if token.type == tokenize.NAME}


def code_words():
    return {word for path in checked_files() if path.suffix == ".py" and "src" in path.parts
            for word in python_names(path)}


def test_the_glossary_lists_the_quantities_with_one_code_name_each():
    rows = quantities()
    assert len(rows) >= 25
    code_names = [name for row in rows for name in names(row["code name"])]
    assert len(code_names) == len(set(code_names))
    refused = [name for row in rows for name in names(row["refused"])]
    assert not set(refused) & set(code_names)
    amplitude = next(row for row in rows if row["quantity"].startswith("injection amplitude"))
    assert names(amplitude["code name"]) == ["injection_amplitude_V"]
    assert {"amplitude_V", "injection_amplitude"} <= set(names(amplitude["key where it differs"]))
    assert {"hf_amplitude_V", "U_h"} <= set(names(amplitude["refused"]))


def test_every_code_name_of_the_glossary_is_in_the_code():
    words = code_words()
    missing = [name for row in quantities() for name in names(row["code name"]) if name not in words]
    assert missing == []


def test_no_refused_synonym_in_code_shipped_files_or_docs():
    """A refused name that is a paper's symbol (U_h) fails only as a Python identifier; any other fails
    wherever it stands as a word."""
    rows = quantities()
    symbols = {name for row in rows for name in names(row["refused"]) if name in row["symbol"]}
    words = {name for row in rows for name in names(row["refused"])} - symbols
    pattern = re.compile(r"(?<![A-Za-z0-9_])(" + "|".join(sorted(words)) + r")(?![A-Za-z0-9_])")
    found = []
    for path in checked_files():
        text = path.read_text()
        found += [f"{path.relative_to(ROOT)}: {match}" for match in sorted(set(pattern.findall(text)))]
        if path.suffix == ".py":
            found += [f"{path.relative_to(ROOT)}: identifier {name}" for name in sorted(python_names(path) & symbols)]
    assert found == []


def test_the_rule_finds_a_synonym_as_a_word_and_a_symbol_as_an_identifier(tmp_path):
    code = tmp_path / "code.py"
    code.write_text('"""The carrier U_h cos ω_h t."""\nU_h = conditions["hf_amplitude_V"]\n')
    assert python_names(code) >= {"U_h", "conditions"} and "hf_amplitude_V" not in python_names(code)
    assert re.search(r"(?<![A-Za-z0-9_])hf_amplitude_V(?![A-Za-z0-9_])", code.read_text())

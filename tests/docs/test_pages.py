"""The documentation's structure: pages that docstrings and the README point to exist, with
the sections they name; the front page stays short. (``make docs`` builds the site itself.)"""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
CODE = ("excite", "envs", "agents")


def _headings(page: Path) -> set[str]:
    return {m.group(1).strip() for m in re.finditer(r"^#+ (.+)$", page.read_text(), re.M)}


def test_every_docs_page_a_docstring_names_exists_with_the_section_it_names():
    cited = re.compile(r"docs/([\w/-]+\.md)(?:,\s*\n?\s*\"([^\"]+)\")?")
    seen = 0
    for package in CODE:
        for source in (ROOT / package).rglob("*.py"):
            for page, section in cited.findall(source.read_text()):
                seen += 1
                assert (DOCS / page).is_file(), f"{source}: docs/{page} does not exist"
                if section:
                    assert section in _headings(DOCS / page), (
                        f"{source}: docs/{page} has no section {section!r}")
    assert seen > 0


@pytest.mark.parametrize(("page", "section"), [
    ("conventions.md", "Information"),
    ("conventions.md", "Sensor pose"),
    ("formats.md", "Time-series logs"),
])
def test_the_sections_docstrings_rely_on_exist(page, section):
    assert section in _headings(DOCS / page)


def test_every_page_is_in_the_site_navigation():
    nav = (ROOT / "mkdocs.yml").read_text()
    for page in DOCS.rglob("*.md"):
        assert page.relative_to(DOCS).as_posix() in nav, f"{page} is not in mkdocs.yml's nav"


def test_the_readme_is_a_short_front_page_whose_links_resolve():
    readme = ROOT / "README.md"
    assert len(readme.read_text().splitlines()) < 200
    for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", readme.read_text()):
        if "://" not in target:
            assert (ROOT / target).exists(), f"README.md links to {target}, which is missing"


def _dotted_names() -> set[str]:
    """Every ``excite.…``, ``envs.…`` or ``agents.…`` name the reference pages show in code."""
    pages = [p for p in DOCS.glob("*.md")]
    found = set()
    for page in pages:
        for span in re.findall(r"`([^`\n]+)`", page.read_text()):
            found.update(re.findall(r"\b((?:excite|envs|agents)(?:\.[A-Za-z_]\w*)+)", span))
    return found


def test_every_name_the_reference_pages_give_exists():
    import importlib

    missing = []
    for name in sorted(_dotted_names()):
        parts = name.split(".")
        for cut in range(len(parts), 0, -1):
            try:
                obj = importlib.import_module(".".join(parts[:cut]))
            except ImportError:
                continue
            try:
                for attribute in parts[cut:]:
                    obj = getattr(obj, attribute)
            except AttributeError:
                missing.append(name)
            break
        else:
            missing.append(name)
    assert not missing, f"named in docs/*.md but not found: {missing}"


def test_the_environment_page_shows_the_generated_configuration_table():
    """The page carries the marker the docs hook replaces with the table of every key, and
    the hook renders a row per key from their one source."""
    import importlib.util

    from envs.config import CONFIG_KEYS

    spec = importlib.util.spec_from_file_location("hook", DOCS / "hooks" / "config_reference.py")
    hook = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hook)
    text = (DOCS / "environment.md").read_text()
    assert hook.MARKER in text
    rendered = hook.on_page_markdown(text, None, None, None)
    assert hook.MARKER not in rendered
    for key in CONFIG_KEYS:
        assert f"| `{key.name}` |" in rendered, key.name

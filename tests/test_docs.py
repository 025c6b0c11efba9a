"""The README and docs/ stay true: the example node shown is the file that runs, every link resolves."""
from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
DOCS = sorted((REPO / "docs").glob("*.md"))


def test_the_readme_shows_the_example_node_that_the_tests_launch() -> None:
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S)
    example = (REPO / "graph_configs" / "examples" / "nodes" / "smooth_markers.py").read_text(encoding="utf-8")
    assert example in blocks, "README's 'Writing a node' differs from graph_configs/examples/nodes/smooth_markers.py"


def test_every_relative_link_in_the_readme_and_docs_resolves() -> None:
    broken = []
    for page in [README, *DOCS, REPO / "tests" / "README.md"]:
        if not page.exists():
            broken.append(f"{page.relative_to(REPO)} (linked from the README) is missing")
            continue
        for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", page.read_text(encoding="utf-8")):
            if "://" not in target and not (page.parent / target).exists():
                broken.append(f"{page.relative_to(REPO)}: {target}")
    assert not broken, "broken links:\n" + "\n".join(broken)


def test_the_readme_stays_a_readme() -> None:
    n = len(README.read_text(encoding="utf-8").splitlines())
    assert n < 380, f"README.md has {n} lines: put the detail in docs/"


def test_every_path_the_docs_name_in_backquotes_exists() -> None:
    missing = []
    for page in [README, *DOCS]:
        for path in re.findall(r"`((?:mocapgraph|graph_configs|benchmarks|tests|scripts)/[\w/.-]+\.(?:py|yaml|md|json))`",
                               page.read_text(encoding="utf-8")):
            if not (REPO / path).exists():
                missing.append(f"{page.relative_to(REPO)}: {path}")
    assert not missing, "paths named that do not exist:\n" + "\n".join(missing)

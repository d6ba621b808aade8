"""docs/layout.md is a newcomer's map of the code: it must name every module and script."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def layout_section(doc: str) -> str:
    """The file map of docs/layout.md: its first fenced block."""
    start = doc.index("```\n") + 4
    return doc[start:doc.index("```", start)]


def unmapped(section: str, root: Path = ROOT) -> list[str]:
    """Modules under paper_lib/ and files under scripts/ whose name the section does not mention.

    A module counts as mapped when its file name appears under its package's line (the map is indented
    by package), so `config.py` of the study is checked separately from the pipeline's `config.py`.
    """
    lines = section.splitlines()
    missing = []
    for path in sorted((root / "paper_lib").rglob("*.py")) + sorted((root / "scripts").glob("*")):
        if "__pycache__" in path.parts or path.is_dir():
            continue
        rel = path.relative_to(root)
        package = rel.parent.name if rel.parent.name not in ("paper_lib", "scripts") else None
        if path.name == "__init__.py" and package is not None:
            continue  # a subpackage is mapped by its own `name/` line, checked below
        if package is None:
            found = re.search(rf"(?<![\w/]){re.escape(path.name)}\b", section) is not None
        else:
            found = _listed_under(lines, f"{package}/", path.name)
        if not found:
            missing.append(str(rel))
    for sub in sorted(p for p in (root / "paper_lib").iterdir() if (p / "__init__.py").is_file()):
        if not re.search(rf"(?<![\w/]){re.escape(sub.name)}/", section):
            missing.append(f"paper_lib/{sub.name}/")
    return missing


def _listed_under(lines: list[str], header: str, name: str) -> bool:
    """Whether `name` appears on a line indented deeper than the line that opens `header`."""
    for i, line in enumerate(lines):
        if line.strip().startswith(header):
            depth = len(line) - len(line.lstrip())
            for below in lines[i + 1:]:
                if below.strip() and len(below) - len(below.lstrip()) <= depth:
                    break
                if re.search(rf"(?<![\w/]){re.escape(name)}\b", below):
                    return True
    return False


def test_layout_doc_names_every_module_and_script():
    section = layout_section((ROOT / "docs" / "layout.md").read_text())
    missing = unmapped(section)
    assert not missing, f"docs/layout.md does not name {missing}: add a line for each (what it is for)"


def test_a_new_module_is_reported_missing(tmp_path):
    """The check is real: a module the map does not name is reported, under its own package."""
    section = layout_section((ROOT / "docs" / "layout.md").read_text())
    for rel in ("paper_lib/__init__.py", "paper_lib/agents/factory.py", "paper_lib/study/__init__.py",
                "paper_lib/study/objective.py", "paper_lib/study/new_sampler.py", "paper_lib/extra.py",
                "scripts/land_run.sh"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("")
    assert unmapped(section, tmp_path) == ["paper_lib/extra.py", "paper_lib/study/new_sampler.py"]
    (tmp_path / "paper_lib" / "guard").mkdir()
    (tmp_path / "paper_lib" / "guard" / "config.py").write_text("")  # config.py is mapped elsewhere, not under guard/
    assert "paper_lib/guard/config.py" in unmapped(section, tmp_path)

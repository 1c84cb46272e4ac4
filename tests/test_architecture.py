"""docs/architecture.md matches the tree: every package it names exists."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_package_named_in_the_architecture_page_exists() -> None:
    text = (ROOT / "docs" / "architecture.md").read_text()
    named = set(re.findall(r"\b((?:cellctl|firmware_io)(?:\.[a-z_]+)*)\b", text))
    assert "cellctl.vision" in named and "firmware_io" in named  # the pattern reads the page
    missing = sorted(name for name in named if importlib.util.find_spec(name) is None)
    assert not missing, f"docs/architecture.md names modules that do not exist: {missing}"


def test_every_cellctl_subpackage_is_on_the_page() -> None:
    text = (ROOT / "docs" / "architecture.md").read_text()
    packages = sorted(p.parent.name for p in (ROOT / "cellctl").glob("*/__init__.py"))
    absent = [name for name in packages if f"cellctl.{name}" not in text]
    assert not absent, f"subpackages missing from docs/architecture.md: {absent}"


def test_every_module_of_the_line_packages_is_on_the_page() -> None:
    """The service, the stereo door and the field side are listed module by module: a moved or new module
    there comes with its line on the page."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    modules = [
        f"{package}.{path.stem}"
        for package, folder in (
            ("cellctl.service", ROOT / "cellctl" / "service"),
            ("cellctl.stereo", ROOT / "cellctl" / "stereo"),
            ("firmware_io", ROOT / "firmware_io"),
        )
        for path in sorted(folder.glob("*.py"))
        if path.stem != "__init__"
    ]
    absent = [name for name in modules if f"`{name}`" not in text]
    assert not absent, f"modules missing from docs/architecture.md (add a line to its module table): {absent}"

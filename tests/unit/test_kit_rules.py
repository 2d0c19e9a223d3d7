"""The tests' one kit: what several test modules share lives in tests/kit (or a tier's
conftest.py, for fixtures), never in a test module that others import.

Every Python file under tests/ and bench/ is read with ``ast``: an import of a test module
(``test_*``) or of a conftest, at the top or inside a function, by ``import``, ``from ...
import`` or by name (importlib.import_module, __import__), fails here with its place.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
READ = [ROOT / "tests", ROOT / "bench"]


def forbidden(module: str) -> bool:
    """Whether ``module`` (a dotted name) is a test module or a conftest."""
    return any(part.startswith("test_") or part == "conftest" for part in module.split("."))


def imports_of_tests(source: str) -> list[tuple[int, int, str]]:
    """(line, column, module) of each import of a test module or conftest in ``source``."""
    found = []
    for node in ast.walk(ast.parse(source)):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):  # `from kit import test_x` names it last
            base = node.module or ""
            whole = [".".join(filter(None, (base, alias.name))) for alias in node.names]
            names = [base] if forbidden(base) else whole
        elif isinstance(node, ast.Call):
            func = node.func
            called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            arg = node.args[0] if node.args else None
            if (
                called in ("import_module", "__import__")
                and isinstance(arg, ast.Constant)
                and isinstance(arg.value, str)
            ):
                names = [arg.value]
        found += [(node.lineno, node.col_offset + 1, n) for n in names if forbidden(n)]
    return found


def python_files() -> list[Path]:
    return sorted(p for folder in READ for p in folder.rglob("*.py") if ".venv" not in p.parts)


def test_no_module_of_the_tests_imports_a_test_module() -> None:
    files = python_files()
    assert any(p.name == "test_kit_rules.py" for p in files)  # the walk reaches the tests
    broken = [
        f"{path.relative_to(ROOT)}:{line}:{col}: imports {module}: move what it shares to "
        "tests/kit (fixtures: a conftest.py)"
        for path in files
        for line, col, module in imports_of_tests(path.read_text())
    ]
    assert not broken, "\n".join(broken)


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("from test_cli import edgerv", [(1, 1, "test_cli")]),
        ("import test_batches as b", [(1, 1, "test_batches")]),
        (
            "def f():\n    from test_engine_columns import engine_with",
            [(2, 5, "test_engine_columns")],
        ),
        ("import importlib\nimportlib.import_module('test_past')", [(2, 1, "test_past")]),
        ("__import__('conftest')", [(1, 1, "conftest")]),
        ("from unit.test_cli import RUN", [(1, 1, "unit.test_cli")]),
        ("from . import test_handler", [(1, 1, "test_handler")]),
        ("from kit.cli import edgerv\nimport testing\nfrom helpers import compiled", []),
    ],
)
def test_the_rule_sees_every_way_of_importing_a_test_module(
    source: str, expected: list[tuple[int, int, str]]
) -> None:
    assert imports_of_tests(source) == expected

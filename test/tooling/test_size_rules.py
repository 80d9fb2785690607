"""The size rules of the product code: no class over MAX_CLASS_LINES lines, no module over
MAX_MODULE_LINES lines except the numba kernel modules (``*_kernels.py`` and the files
of a ``_kernels`` package), whose loops are written out for the compiler."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "grasp_fc_ros"

#: A class a newcomer reads in one sitting: one concern.
MAX_CLASS_LINES = 350
#: A module a newcomer reads in one sitting.
MAX_MODULE_LINES = 800


def is_kernel_module(path: Path) -> bool:
    return path.name.endswith("_kernels.py") or "_kernels" in path.parts


def oversized(source: str, name: str, kernel: bool = False) -> list[str]:
    """What in ``source`` (a module called ``name``) breaks the size rules."""
    found = []
    n_lines = len(source.splitlines())
    if n_lines > MAX_MODULE_LINES and not kernel:
        found.append(f"{name}: {n_lines} lines (at most {MAX_MODULE_LINES})")
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ClassDef):
            first = min([node.lineno] + [d.lineno for d in node.decorator_list])
            size = node.end_lineno - first + 1
            if size > MAX_CLASS_LINES:
                found.append(f"{name}:{node.lineno}: class {node.name} has {size} lines "
                             f"(at most {MAX_CLASS_LINES})")
    return found


def test_no_class_or_module_of_the_package_is_over_size():
    modules = sorted(PACKAGE.rglob("*.py"))
    assert len(modules) > 50, modules  # the package, not an empty folder
    found = [line for path in modules
             for line in oversized(path.read_text(), str(path.relative_to(PACKAGE.parent)),
                                   kernel=is_kernel_module(path))]
    assert not found, "\n".join(found)


def _class_of(n_lines: int, decorated: bool = False) -> str:
    body = "".join(f"    x{i} = {i}\n" for i in range(n_lines - 1))
    return ("@dataclass\n" if decorated else "") + "class Big:\n" + body


def test_the_rules_catch_a_long_class_and_a_long_module():
    assert oversized(_class_of(MAX_CLASS_LINES), "m.py") == []
    assert oversized(_class_of(MAX_CLASS_LINES + 1), "m.py") == [
        f"m.py:1: class Big has {MAX_CLASS_LINES + 1} lines (at most {MAX_CLASS_LINES})"]
    # Decorators count with their class.
    assert len(oversized(_class_of(MAX_CLASS_LINES, decorated=True), "m.py")) == 1
    long_module = "x = 0\n" * (MAX_MODULE_LINES + 1)
    assert oversized(long_module, "m.py") == [
        f"m.py: {MAX_MODULE_LINES + 1} lines (at most {MAX_MODULE_LINES})"]
    assert oversized(long_module, "m_kernels.py", kernel=True) == []


def test_kernel_modules_are_told_apart_by_name():
    assert is_kernel_module(PACKAGE / "core" / "quality" / "epsilon_kernels.py")
    assert is_kernel_module(PACKAGE / "core" / "_kernels" / "cones.py")
    assert not is_kernel_module(PACKAGE / "core" / "quality" / "epsilon.py")

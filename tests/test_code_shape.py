"""crawler/ and hw_sim/ keep the code shape of the brief: modules under 400 lines, functions under 60;
hw_sim never imports crawler."""
import ast
from pathlib import Path

import hw_sim

ROOT = Path(hw_sim.__file__).parent
ROOTS = (ROOT, ROOT.parent / "crawler")


def _functions(tree):
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            start = min([node.lineno] + [d.lineno for d in node.decorator_list])
            yield node.name, node.end_lineno - start + 1


def test_modules_and_functions_are_short():
    too_long = []
    for path in sorted(p for root in ROOTS for p in root.rglob("*.py")):
        src, name = path.read_text(), path.relative_to(ROOT.parent)
        if src.count("\n") > 400:
            too_long.append(f"{name}: {src.count(chr(10))} lines")
        too_long += [f"{name}: {fn}() {n} lines" for fn, n in _functions(ast.parse(src)) if n > 60]
    assert not too_long, too_long


def test_hw_sim_never_imports_crawler():
    for path in sorted(ROOT.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else []
            assert not any(n.split(".")[0] == "crawler" for n in names), path

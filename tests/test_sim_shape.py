"""hw_sim keeps the code shape of the brief: modules under 400 lines, functions under 60."""
import ast
from pathlib import Path

import hw_sim

ROOT = Path(hw_sim.__file__).parent


def _functions(tree):
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            start = min([node.lineno] + [d.lineno for d in node.decorator_list])
            yield node.name, node.end_lineno - start + 1


def test_modules_and_functions_are_short():
    too_long = []
    for path in sorted(ROOT.rglob("*.py")):
        src = path.read_text()
        if src.count("\n") > 400:
            too_long.append(f"{path.relative_to(ROOT)}: {src.count(chr(10))} lines")
        too_long += [f"{path.relative_to(ROOT)}: {name}() {n} lines"
                     for name, n in _functions(ast.parse(src)) if n > 60]
    assert not too_long, too_long


def test_hw_sim_never_imports_crawler():
    for path in sorted(ROOT.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else []
            assert not any(n.split(".")[0] == "crawler" for n in names), path

"""List modules over 500 lines and functions over 80 lines in the package (not tests).

Usage: python scripts/check_size.py   (exit 1 if anything is over; there are no exceptions)
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "mocap_calib"
MAX_MODULE = 500
MAX_FUNCTION = 80

def oversized(max_module: int = MAX_MODULE,
              max_function: int = MAX_FUNCTION) -> list[tuple[str, str | None, int]]:
    """(module path, function name or None for the module, lines) over the limits."""
    out = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = str(path.relative_to(PACKAGE.parent))
        src = path.read_text()
        n = len(src.splitlines())
        if n > max_module:
            out.append((rel, None, n))
        for node in ast.walk(ast.parse(src)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = node.end_lineno - node.lineno + 1
                if length > max_function:
                    out.append((rel, node.name, length))
    return out


def main() -> int:
    bad = oversized()
    for x in bad:
        what = x[0] if x[1] is None else f"{x[0]}:{x[1]}"
        print(f"{what}: {x[2]} lines")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())

"""List modules over 500 lines and functions over 80 lines in the package (not tests).

Usage: python scripts/check_size.py   (exit 1 if anything is over and not in ALLOWED)
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "mocap_calib"
MAX_MODULE = 500
MAX_FUNCTION = 80

#: Over the limit on purpose, with the reason (DEVELOPERS.md repeats them).
ALLOWED: dict[str, str] = {}


def oversized() -> list[str]:
    out = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = str(path.relative_to(PACKAGE.parent))
        src = path.read_text()
        n = len(src.splitlines())
        if n > MAX_MODULE:
            out.append(f"{rel}: {n} lines")
        for node in ast.walk(ast.parse(src)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = node.end_lineno - node.lineno + 1
                if length > MAX_FUNCTION:
                    out.append(f"{rel}:{node.lineno} {node.name}: {length} lines")
    return out


def main() -> int:
    bad = [x for x in oversized() if x.split(" ")[0].rstrip(":") not in ALLOWED
           and x.split(":")[0] + ":" + x.split(" ")[1].rstrip(":") not in ALLOWED]
    for x in oversized():
        print(x)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())

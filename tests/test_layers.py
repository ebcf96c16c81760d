"""The library never imports the web layer: importing every ``cascalib`` module leaves
``service``, ``fastapi`` and ``sqlalchemy`` out of ``sys.modules``."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cascalib

WEB = ("service", "api_schemas", "fastapi", "sqlalchemy")

_SCRIPT = """
import importlib, json, pkgutil, sys
import cascalib
names = sorted(m.name for m in pkgutil.walk_packages(cascalib.__path__, "cascalib.")
               if not m.name.endswith("__main__"))
for name in names:
    importlib.import_module(name)
web = sorted({m.split(".")[0] for m in sys.modules} & set(sys.argv[1:]))
print(json.dumps({"modules": names, "web": web}))
"""


def test_no_cascalib_module_imports_the_web_layer() -> None:
    r = subprocess.run([sys.executable, "-c", _SCRIPT, *WEB], capture_output=True, text=True,
                       timeout=300, cwd=Path(cascalib.__file__).parents[1])
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert "cascalib.cli.serve" in out["modules"] and len(out["modules"]) > 50
    assert out["web"] == []


def test_no_cascalib_source_names_the_web_layer_in_an_import() -> None:
    """Imports inside functions too (``cascalib serve`` finds the service by entry point)."""
    import ast

    found = []
    for path in Path(cascalib.__file__).parent.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            found += [f"{path.name}:{node.lineno} {n}" for n in names  # type: ignore[attr-defined]
                      if n.split(".")[0] in WEB]
    assert found == []

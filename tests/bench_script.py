"""Load a ``bench/`` script as a module for a test fixture (the scripts are not a package)."""
from __future__ import annotations

import importlib.util
import sys
from collections.abc import Iterator
from pathlib import Path


def script_module(path: Path, name: str) -> Iterator:
    """Yield ``path`` executed as module ``name``; registered in ``sys.modules`` while in use.

    Registered because the scripts' dataclasses look their module up by name; removed after.
    Use as ``yield from script_module(SCRIPT, "name")`` in a module-scoped fixture.
    """
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(name, None)

"""The safe files of a run directory: JSON written atomically (``outdir.write_text_atomic``: a kill
leaves the old or the new file) and checkpoint state that loads with ``torch.load(...,
weights_only=True)`` (nothing pickled). torch is imported only to save or load state."""

from __future__ import annotations

import io
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from lowcostdex.outdir import write_bytes_atomic, write_text_atomic


def json_scalar(value: Any) -> Any:
    """``json.dumps``'s ``default``: a numpy scalar (``seed=np.int64(3)`` from ``np.arange``,
    ``gamma=np.float32(0.99)``) is written as the Python number it holds; anything else is
    refused as ``json`` refuses it."""
    if isinstance(value, np.generic) and isinstance(value.item(), (bool, int, float, str)):
        return value.item()
    raise TypeError(f"Object of type {type(value).__name__} is not JSON serializable")


def write_json(path: str | os.PathLike[str], obj: Any, *, sort_keys: bool = True) -> None:
    """Atomically write ``obj`` as indented JSON (non-finite floats are written as NaN/Infinity;
    numpy scalars as the numbers they hold)."""
    write_text_atomic(path, json.dumps(obj, indent=2, sort_keys=sort_keys, default=json_scalar)
                      + "\n")


def read_json(path: str | os.PathLike[str]) -> Any:
    """Read a JSON file."""
    return json.loads(Path(path).read_text(encoding="utf-8"))


def to_safe(value: Any, where: str) -> Any:
    """Convert ``value`` into types ``torch.load(weights_only=True)`` accepts, or raise."""
    import torch

    if isinstance(value, torch.Tensor):
        return value.detach().cpu().clone()
    if isinstance(value, np.ndarray):
        # np.array, not np.ascontiguousarray: the latter turns a 0-d array into shape (1,)
        return torch.from_numpy(np.array(value, order="C", copy=True))
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, Mapping):
        out = {}
        for key, item in value.items():
            if not isinstance(key, (str, int)):
                raise TypeError(f"checkpoint key {key!r} at {where} must be str or int")
            out[key] = to_safe(item, f"{where}.{key}")
        return out
    if isinstance(value, (list, tuple)):
        items = [to_safe(item, f"{where}[{i}]") for i, item in enumerate(value)]
        return items if isinstance(value, list) else tuple(items)
    raise TypeError(
        f"checkpoint value at {where} has type {type(value).__name__}; store tensors, numpy "
        "arrays, numbers, strings, None and lists/dicts of them (e.g. a state_dict())"
    )


def save_state(path: str | os.PathLike[str], state: Mapping[str, Any]) -> None:
    """Atomically save a checkpoint dict in a format that loads with ``weights_only=True``.

    Args:
      path: destination file (``.pt``).
      state: tensors, numpy arrays (stored as tensors), numbers, strings, None, and nested
        dicts/lists/tuples of these, e.g. ``module.state_dict()``,
        ``optimizer.state_dict()``, ``generator.get_state()``, ``rng.bit_generator.state``.

    Raises:
      TypeError: if ``state`` holds anything else (arbitrary objects are never pickled).
    """
    import torch

    buf = io.BytesIO()
    torch.save(to_safe(dict(state), "state"), buf)
    write_bytes_atomic(path, buf.getvalue())


def load_state(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Load a checkpoint written by :func:`save_state` with ``weights_only=True``."""
    import torch

    return torch.load(Path(path), map_location="cpu", weights_only=True)

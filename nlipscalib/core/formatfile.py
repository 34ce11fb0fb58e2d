"""Reading the JSON header every workbench format carries (``format``, ``format_version``), checked once."""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import CaptureError


def read_format_json(path: str | Path, name: str, version: int, *, required=(), missing_hint: str = "") -> dict:
    """Read a JSON file of format ``name`` and version ``version``; every problem names the file.

    Parameters
    ----------
    path : the JSON file (meta.json, report.json, index.json ...)
    name, version : the expected ``format`` and ``format_version`` values
    required : top-level keys that must be present
    missing_hint : appended to the message when the file does not exist (what the user should run)

    Raises
    ------
    CaptureError -- missing, not JSON, another format or version, or a required key missing.
    """
    path = Path(path)
    if not path.is_file():
        raise CaptureError(f"{path}: missing" + (f"; {missing_hint}" if missing_hint else ""))
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CaptureError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != name:
        raise CaptureError(f"{path}: 'format' must be {name!r}")
    if data.get("format_version") != version:
        raise CaptureError(
            f"{path}: format_version {data.get('format_version')!r} is not supported (expected {version})"
        )
    for key in required:
        if key not in data:
            raise CaptureError(f"{path}: missing key '{key}'")
    return data

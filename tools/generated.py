"""Write generated files, or (``--check``) say which of them differ from what would be written."""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path


def write_or_check(files: Mapping[Path, str], check: bool, what: str, tool: str) -> int:
    """Write every ``path -> text`` of ``files`` (``check``: compare instead); 1 if any is stale."""
    stale = []
    for path, text in files.items():
        path.parent.mkdir(parents=True, exist_ok=True)
        if check:
            if not path.exists() or path.read_text() != text:
                stale.append(path.name)
        else:
            path.write_text(text)
    if stale:
        print(f"stale {what} (run python tools/{tool}):", ", ".join(stale))
        return 1
    return 0

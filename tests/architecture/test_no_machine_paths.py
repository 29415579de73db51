"""The tree holds the product only: no absolute path of a particular machine in any source,
test, tool, benchmark or document."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TOP_FILES = ("README.md", "CONTRIBUTING.md", "Makefile", "pyproject.toml")
TREES = ("protocol", "firmware_sim", "ersac_hil", "tools", "bench", "tests", "docs", ".ci")
SUFFIXES = {".py", ".md", ".toml", ".json5", ".json", ".xml", ".eds", ".cfg", ".txt", ".sh", ""}
# a home, checkout or scratch directory of some machine (work, root, home, Users at the top)
MACHINE_PATH = re.compile(r"(?<![\w.~-])/(?:" + "|".join(("work", "root", "home", "Users")) + r")/")


def _files():
    yield from (ROOT / name for name in TOP_FILES if (ROOT / name).is_file())
    for tree in TREES:
        for path in sorted((ROOT / tree).rglob("*")):
            if path.is_file() and path.suffix in SUFFIXES and "__pycache__" not in path.parts:
                yield path


def test_no_absolute_machine_paths():
    found = []
    for path in _files():
        for n, line in enumerate(path.read_text(errors="replace").splitlines(), start=1):
            if MACHINE_PATH.search(line):
                found.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert not found, "machine paths in the tree:\n" + "\n".join(found)

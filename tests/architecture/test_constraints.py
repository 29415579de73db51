"""constraints.txt pins the environment ``make test`` and CI install: every dependency the
project declares (extras included) is pinned there to one version, inside pyproject's range - a
dependency left out would be resolved afresh on every new machine (mujoco 4.0.1 did so and
changed the bracing physics under the golden records)."""

import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[2]


def _pins() -> dict[str, Version]:
    pins: dict[str, Version] = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        name, sep, version = line.partition("==")
        assert sep and version, f"constraints.txt: {line!r} is not an exact pin (name==version)"
        key = canonicalize_name(name)
        assert key not in pins, f"constraints.txt pins {name} twice"
        pins[key] = Version(version)
    return pins


def _declared() -> list[Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project.get("optional-dependencies", {})
    return [Requirement(r) for r in (*project["dependencies"], *(r for rs in extras.values() for r in rs))]


def test_every_declared_dependency_is_pinned_inside_its_range():
    pins = _pins()
    for req in _declared():
        name = canonicalize_name(req.name)
        assert name in pins, f"{req.name} is declared in pyproject.toml but not pinned in constraints.txt"
        assert req.specifier.contains(pins[name], prereleases=True), \
            f"constraints.txt pins {req.name}=={pins[name]}, outside pyproject's {req.specifier}"


def test_the_project_itself_is_not_pinned():
    """A pin of ersac-hil would make ``pip install -c constraints.txt -e .`` refuse the tree's
    own version the moment it changes (``pip freeze`` without ``--exclude-editable`` writes one)."""
    assert "ersac-hil" not in _pins()

"""One TOML reader for every TOML input: a file that cannot be read or parsed is one line
naming the file and the cause, raised as the caller's own error type."""
from __future__ import annotations

import pytest

from ersac_hil.daemon.config import ConfigError, load_toml
from firmware_sim.plant.overrides import PhysicsError, PhysicsOverrides
from protocol.robot import DescriptionError, load_description
from protocol.tomlfile import read_toml


class Refused(Exception):
    pass


def test_a_table_is_read(tmp_path):
    path = tmp_path / "ok.toml"
    path.write_text('a = 1\n[b]\nc = "x"\n')
    assert read_toml(path, Refused) == {"a": 1, "b": {"c": "x"}}


@pytest.mark.parametrize("content, cause", [
    (None, r"cannot read it \(No such file or directory\)"),
    ("dir", r"cannot read it \(Is a directory\)"),
    (b"a = = 1\n", r"not valid TOML: .*line 1"),
    (b"a = \"\xff\"\n", r"not valid TOML: not UTF-8 \(byte 5\)"),
])
def test_a_bad_file_is_one_line_naming_it_and_the_cause(tmp_path, content, cause):
    path = tmp_path / "bad.toml"
    if content == "dir":
        path.mkdir()
    elif content is not None:
        path.write_bytes(content)
    with pytest.raises(Refused, match=rf"^cfg {path}: {cause}") as info:
        read_toml(path, Refused, "cfg ")
    assert "\n" not in str(info.value)
    for error, read in ((ConfigError, load_toml), (PhysicsError, PhysicsOverrides.load),
                        (DescriptionError, load_description)):
        with pytest.raises(error, match=cause):
            read(str(path))

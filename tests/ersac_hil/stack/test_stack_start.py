"""A stack's start-up stops at a Ctrl-C: nothing is started once ``stop`` is set, and every
process started before it is gone after ``close`` (real router and simulators; the stop
comes right after a drawn child was launched, from the stack's own ``launch``)."""
from __future__ import annotations

import os
import threading

import pytest

from ersac_hil.lifecycle import descendants
from ersac_hil.stack import ChildFailed, Stack

pytestmark = pytest.mark.timeout(180)


class StoppedAfter(Stack):
    """A stack whose ``stop`` is set (a Ctrl-C) as soon as the child ``name`` has been launched."""

    def __init__(self, name: str, *args, **kwargs) -> None:  # noqa: ANN002, ANN003
        super().__init__(*args, **kwargs)
        self._stop_after = name
        self.launched: list[str] = []

    def launch(self, name, argv, echo=None):  # noqa: ANN001, ANN201
        child = super().launch(name, argv, echo)
        self.launched.append(name)
        if name == self._stop_after:
            self.stop.set()
        return child


def test_a_stop_before_start_starts_nothing(tmp_path):
    stop = threading.Event()
    stop.set()
    before = set(descendants(os.getpid()))
    with Stack(tmp_path / "logs", stop, say=lambda line: None, pairs=3) as stack:
        with pytest.raises(ChildFailed, match="interrupted"):
            stack.start()
        assert stack.children == []
    assert set(descendants(os.getpid())) <= before


@pytest.mark.parametrize("name", ["router", "sim1", "sim2"])
def test_a_stop_while_the_simulators_start_starts_no_more_and_leaves_none(tmp_path, name):
    """``reproduce --pairs N --oversubscribe`` got its Ctrl-C while it launched simulators and
    launched every one of the rest first (the start loop never looked at ``stop``): here the
    children after ``name`` are never launched, and none of those before outlives ``close``."""
    before = set(descendants(os.getpid()))
    stack = StoppedAfter(name, tmp_path / "logs", threading.Event(), say=lambda line: None, pairs=3)
    with stack:
        with pytest.raises(ChildFailed, match="interrupted"):
            stack.start()
        order = ["router", "sim1", "sim2", "sim3"]
        assert stack.launched == order[:order.index(name) + 1]
        started = list(stack.children)
    assert all(not c.alive() for c in started)
    assert set(descendants(os.getpid())) <= before, "a child of the stack outlived its close()"

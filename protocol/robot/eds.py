"""The object dictionaries of the EDS files a description names, parsed once with canopen."""
from __future__ import annotations

import functools

import canopen
from canopen.objectdictionary import ObjectDictionary

from protocol.robot.model import eds_path


@functools.lru_cache(maxsize=None)
def object_dictionary_file(eds: str, node_id: int) -> ObjectDictionary:
    """The object dictionary of EDS file ``eds`` (a shipped name or an absolute path) with
    ``$NODEID`` resolved to ``node_id``. Shared and cached: treat it as read-only."""
    return canopen.import_od(str(eds_path(eds)), node_id)

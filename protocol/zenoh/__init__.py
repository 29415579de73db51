"""The Zenoh contract between the learner daemon and the robot-side agent.

Pure data: key-expression builders, task parameter spaces and versioned JSON payloads with
validation. No sessions, sockets or threads here (see ``ersac_hil.zenoh_session`` for those).

Typical use::

    from protocol.zenoh import KeySpace, EpisodeRequest, EpisodeResult, ErrorReply, PayloadError

    ks = KeySpace("ubot1")
    payload = EpisodeRequest("ep-0001", "bracing", (0.4,), seed=7).to_json()
    try:
        request = EpisodeRequest.from_json(payload)
    except PayloadError as exc:
        query.reply_err(ErrorReply.from_exception(exc).to_json())

See ``docs/zenoh.md`` for the key table and an example of every payload.
"""

from .codec import MAX_PAYLOAD_BYTES, FrozenMap
from .episode import (
    FAILURE_FLAGS,
    MAX_DURATION_S,
    SEED_MAX,
    STATUSES,
    EpisodeDone,
    EpisodeRequest,
    EpisodeResult,
)
from .errors import (
    InvalidField,
    KeySpaceError,
    MalformedPayload,
    PayloadError,
    PayloadTooLarge,
    UnsupportedVersion,
)
from .keys import CHUNK_PATTERN, DEFAULT_PREFIX, KeySpace, validate_chunk
from .learner import (
    GRID_MAX,
    GRID_MIN,
    KAPPA_MAX,
    KAPPA_MIN,
    LEARNER_STATUSES,
    MAX_CRITIC_POINTS,
    CriticPoint,
    CriticQuery,
    CriticReply,
    KappaCommand,
    LearnerEpisode,
    LearnerState,
    SelectQuery,
    SelectReply,
    WeightsCommand,
)
from .messages import (
    AGENT_PHASES,
    AgentState,
    EstopCommand,
    ERROR_CODES,
    SUPPORTED_VERSIONS,
    VERSION,
    ErrorReply,
    Message,
    decode,
    message_types,
)
from .tasks import TASK_NAMES, TASKS, TaskSpec, damaged, get_task

__all__ = [
    # keys
    "KeySpace", "DEFAULT_PREFIX", "CHUNK_PATTERN", "validate_chunk",
    # errors
    "KeySpaceError", "PayloadError", "MalformedPayload", "PayloadTooLarge",
    "UnsupportedVersion", "InvalidField",
    # envelope
    "VERSION", "SUPPORTED_VERSIONS", "MAX_PAYLOAD_BYTES", "Message", "decode", "message_types",
    "FrozenMap",
    # tasks
    "TaskSpec", "TASKS", "TASK_NAMES", "get_task", "damaged",
    # episode
    "EpisodeRequest", "EpisodeResult", "EpisodeDone",
    "STATUSES", "FAILURE_FLAGS", "SEED_MAX", "MAX_DURATION_S",
    # learner
    "LearnerState", "CriticQuery", "CriticPoint", "CriticReply", "KappaCommand",
    "WeightsCommand", "SelectQuery", "SelectReply", "LearnerEpisode",
    "KAPPA_MIN", "KAPPA_MAX", "LEARNER_STATUSES", "MAX_CRITIC_POINTS", "GRID_MIN", "GRID_MAX",
    # errors on the wire
    "ErrorReply", "ERROR_CODES",
    # safety: e-stop and the agent's state
    "EstopCommand", "AgentState", "AGENT_PHASES",
]

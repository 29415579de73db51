"""The Zenoh key space of one robot.

All keys live under ``<prefix>/<robot>`` (default prefix ``ersac``)::

    ersac/<robot>/agent/alive        liveliness token declared by the agent
    ersac/<robot>/agent/session/<zid> liveliness token of the agent's session (its Zenoh id):
                                     the learner accepts episode replies from these only
    ersac/<robot>/episode/run        queryable (agent): EpisodeRequest -> EpisodeResult | ErrorReply
    ersac/<robot>/episode/done       publication (agent): EpisodeDone
    ersac/<robot>/learner/state      queryable (learner): -> LearnerState
    ersac/<robot>/learner/critic     queryable (learner): ?theta=...|grid=N -> CriticReply
    ersac/<robot>/learner/kappa      subscription (learner): KappaCommand
    ersac/<robot>/learner/weights    subscription (learner): WeightsCommand
    ersac/<robot>/learner/select     queryable (learner): ?kappa=...;weights=...;adopt=... -> SelectReply
    ersac/<robot>/learner/episodes   publication (learner): LearnerEpisode; queryable: the run so far
    ersac/<robot>/learner/error      publication (learner): ErrorReply for every refused put
    ersac/<robot>/agent/estop        subscription (agent): EstopCommand (operator only)
    ersac/<robot>/agent/state        queryable (agent): -> AgentState (waiting for go, stopped...)

Zenoh key rules enforced here: chunks are non-empty (no leading, trailing or doubled ``/``),
and contain no wildcard or selector characters (``*``, ``$``, ``?``, ``#``) nor whitespace.
We are stricter than Zenoh: every chunk must match :data:`CHUNK_PATTERN`. Query parameters
are never part of a key; they go in the selector (:meth:`KeySpace.selector`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from .codec import format_parameters
from .errors import KeySpaceError

__all__ = ["CHUNK_PATTERN", "DEFAULT_PREFIX", "KeySpace", "validate_chunk"]

#: One key chunk: starts with an alphanumeric, then alphanumerics, ``_``, ``-``, ``.``.
CHUNK_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.\-]{0,63}")
DEFAULT_PREFIX = "ersac"

_SUFFIXES = {
    "agent_alive": "agent/alive",
    "agent_go": "agent/go",
    "episode_run": "episode/run",
    "episode_done": "episode/done",
    "learner_state": "learner/state",
    "learner_critic": "learner/critic",
    "learner_kappa": "learner/kappa",
    "learner_weights": "learner/weights",
    "learner_select": "learner/select",
    "learner_episodes": "learner/episodes",
    "learner_error": "learner/error",
}

# -- safety: the e-stop and the agent's own state --------------------------------------------
_SUFFIXES.update({"agent_estop": "agent/estop", "agent_state": "agent/state"})


def validate_chunk(chunk: Any, what: str = "key chunk") -> str:
    """Return ``chunk`` if it is a valid single key chunk, else raise :class:`KeySpaceError`."""
    if not isinstance(chunk, str):
        raise KeySpaceError(f"{what} must be a string, got {type(chunk).__name__}")
    if CHUNK_PATTERN.fullmatch(chunk) is None:
        raise KeySpaceError(
            f"{what} {chunk[:80]!r} is not a valid key chunk: it must match "
            f"{CHUNK_PATTERN.pattern!r} (no '/', '*', '$', '?', '#', whitespace, not empty)"
        )
    return chunk


def _validate_prefix(prefix: Any) -> str:
    if not isinstance(prefix, str) or not prefix:
        raise KeySpaceError(f"prefix must be a non-empty string, got {prefix!r}")
    for chunk in prefix.split("/"):
        validate_chunk(chunk, f"prefix chunk of {prefix[:80]!r}")
    return prefix


@dataclass(frozen=True)
class KeySpace:
    """Key expressions of one robot.

    Example::

        ks = KeySpace("ubot1")            # prefix "ersac"
        ks.episode_run                    # "ersac/ubot1/episode/run"
        ks.selector(ks.learner_critic, "theta=0.4")   # "ersac/ubot1/learner/critic?theta=0.4"

    Args:
        robot: one key chunk naming the robot.
        prefix: one or more chunks joined by ``/`` (default ``"ersac"``).

    Raises:
        KeySpaceError: invalid robot or prefix.
    """

    robot: str
    prefix: str = DEFAULT_PREFIX

    def __post_init__(self) -> None:
        validate_chunk(self.robot, "robot name")
        _validate_prefix(self.prefix)

    @property
    def root(self) -> str:
        """``<prefix>/<robot>``."""
        return f"{self.prefix}/{self.robot}"

    def _key(self, name: str) -> str:
        return f"{self.root}/{_SUFFIXES[name]}"

    @property
    def agent_alive(self) -> str:
        """Liveliness token of the agent."""
        return self._key("agent_alive")

    def agent_session(self, zid: Any) -> str:
        """Liveliness token naming the agent's Zenoh session id (``str(session.info.zid())``),
        declared next to :attr:`agent_alive`: an episode reply whose replier is not such a
        session is not the agent's."""
        return f"{self.root}/agent/session/{validate_chunk(str(zid), 'session id')}"

    @property
    def agent_sessions(self) -> str:
        """``<root>/agent/session/*``: the agent session tokens (the learner subscribes)."""
        return f"{self.root}/agent/session/*"

    @property
    def agent_go(self) -> str:
        """Put by a person who reset a robot without a test bench: the agent may start."""
        return self._key("agent_go")

    @property
    def agent_estop(self) -> str:
        """Put by an operator: engage (or release) the emergency stop of the robot."""
        return self._key("agent_estop")

    @property
    def agent_state(self) -> str:
        """Queryable on the agent: its ``AgentState`` (ready, waiting for go, running, stopped)."""
        return self._key("agent_state")

    @property
    def episode_run(self) -> str:
        """Queryable on the agent running one episode."""
        return self._key("episode_run")

    @property
    def episode_done(self) -> str:
        """Publication of every episode the agent finished."""
        return self._key("episode_done")

    @property
    def learner_state(self) -> str:
        """Queryable: the learner's current state."""
        return self._key("learner_state")

    @property
    def learner_critic(self) -> str:
        """Queryable: critic predictions at points or on a grid."""
        return self._key("learner_critic")

    @property
    def learner_kappa(self) -> str:
        """Put target: change the risk sensitivity kappa."""
        return self._key("learner_kappa")

    @property
    def learner_weights(self) -> str:
        """Put target: re-weight the cost terms."""
        return self._key("learner_weights")

    @property
    def learner_select(self) -> str:
        """Queryable: offline policy selection for a kappa (and weights)."""
        return self._key("learner_select")

    @property
    def learner_episodes(self) -> str:
        """Publication of every episode the learner recorded; a query gets the run's history."""
        return self._key("learner_episodes")

    @property
    def learner_error(self) -> str:
        """Publication of an ``ErrorReply`` for every refused put (kappa, weights): a put has
        no reply channel, so refusals are reported here."""
        return self._key("learner_error")

    @property
    def learner_all(self) -> str:
        """``<root>/learner/**``: every learner key (for monitors)."""
        return f"{self.root}/learner/**"

    def keys(self) -> dict[str, str]:
        """All concrete keys by attribute name, e.g. ``{"episode_run": "ersac/r1/episode/run"}``."""
        return {name: self._key(name) for name in _SUFFIXES}

    @staticmethod
    def selector(key: str, parameters: str | dict[str, str] | None = None) -> str:
        """``key?parameters`` (or ``key`` when there are none).

        Args:
            key: a concrete key from this class.
            parameters: ``"a=1;b=2"`` text or a mapping (see ``to_parameters()`` of the
                query messages).
        """
        if "?" in key or "#" in key:
            raise KeySpaceError(f"key {key!r} already contains a selector")
        text = format_parameters(parameters) if isinstance(parameters, dict) else parameters
        return f"{key}?{text}" if text else key

    @staticmethod
    def alive_pattern(prefix: str = DEFAULT_PREFIX) -> str:
        """``<prefix>/*/agent/alive``: liveliness tokens of every robot under ``prefix``."""
        return f"{_validate_prefix(prefix)}/*/{_SUFFIXES['agent_alive']}"

    @classmethod
    def from_key(cls, key: str, prefix: str = DEFAULT_PREFIX) -> KeySpace:
        """The key space a concrete key belongs to (e.g. from a liveliness sample).

        Raises:
            KeySpaceError: ``key`` is not ``<prefix>/<robot>/<known suffix>``.
        """
        _validate_prefix(prefix)
        head = prefix + "/"
        if not isinstance(key, str) or not key.startswith(head):
            raise KeySpaceError(f"key {key!r} is not under prefix {prefix!r}")
        robot, _, suffix = key[len(head):].partition("/")
        if suffix not in _SUFFIXES.values():
            raise KeySpaceError(f"key {key!r} has no known suffix after the robot name")
        return cls(robot, prefix)

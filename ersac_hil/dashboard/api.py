"""The dashboard's JSON control endpoints: request bodies -> protocol commands, errors -> HTTP.

Bodies are checked by the protocol's own decoder and message constructors (the checks the CLI
and the learner use), so the dashboard refuses exactly what they refuse:

=====================  ==============================================  ========================
endpoint               body                                            protocol object
=====================  ==============================================  ========================
``POST /api/kappa``    ``{"kappa": 1.5}``                              ``KappaCommand``
``POST /api/weights``  ``{"weights": {"arm_power": 20}}`` (partial)    ``WeightsCommand``
``POST /api/select``   ``{"kappa": 1.5}`` [``"weights": {...}``]       ``SelectQuery(adopt=False)``
``POST /api/adopt``    same as select                                  ``SelectQuery(adopt=True)``
=====================  ==============================================  ========================

Weight names are also checked against the learner's task (``TaskSpec.check_weights`` on the
current weights merged with the given ones), as the learner would.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from protocol.zenoh import (
    ErrorReply,
    InvalidField,
    KappaCommand,
    LearnerState,
    PayloadError,
    SelectQuery,
    WeightsCommand,
    get_task,
)
from protocol.zenoh.codec import loads

from ersac_hil.daemon.clients import ClientError, NoAnswer, NotPermitted, RequestRefused

__all__ = ["ApiError", "parse_body", "kappa_command", "weights_command", "select_query",
           "error_from_exception", "FORBIDDEN"]


class ApiError(Exception):
    """A refused request: HTTP ``status`` and the JSON body ``{"error": {code, reason[, field]}}``."""

    def __init__(self, status: int, code: str, reason: str, field: str | None = None) -> None:
        super().__init__(reason)
        self.status, self.code, self.reason, self.field = status, code, reason, field

    def body(self) -> dict[str, Any]:
        error = {"code": self.code, "reason": self.reason}
        if self.field is not None:
            error["field"] = self.field
        return {"error": error}


FORBIDDEN = ApiError(403, "forbidden", "this dashboard is read-only: its Zenoh identity may only observe")


def parse_body(raw: bytes, content_type: str | None) -> Mapping[str, Any]:
    """The JSON object of a request body (strict: the protocol's decoder)."""
    if (content_type or "").split(";")[0].strip().lower() != "application/json":
        raise ApiError(415, "invalid_request", "send the body as Content-Type: application/json")
    return loads(raw)


def _fields(body: Mapping[str, Any], allowed: tuple[str, ...], required: tuple[str, ...]) -> None:
    for key in body:
        if key not in allowed:
            raise InvalidField(str(key)[:80], f"unexpected field; expected {list(allowed)}")
    for key in required:
        if key not in body:
            raise InvalidField(key, "missing field")


def _check_names(weights: Mapping[str, float], state: LearnerState) -> None:
    get_task(state.task).check_weights({**state.weights, **weights})


def kappa_command(body: Mapping[str, Any]) -> KappaCommand:
    """``{"kappa": x}`` with x in [KAPPA_MIN, KAPPA_MAX]."""
    return KappaCommand.from_obj(body)


def weights_command(body: Mapping[str, Any], state: LearnerState) -> WeightsCommand:
    """``{"weights": {term: w >= 0, ...}}``: known terms of the learner's task only."""
    command = WeightsCommand.from_obj(body)
    _check_names(command.weights, state)
    return command


def select_query(body: Mapping[str, Any], state: LearnerState, adopt: bool) -> SelectQuery:
    """``{"kappa": x[, "weights": {...}]}`` -> the offline selection (adopting it or not)."""
    _fields(body, ("kappa", "weights"), ("kappa",))
    query = SelectQuery(body["kappa"], body.get("weights"), adopt)
    if query.weights is not None:
        _check_names(query.weights, state)
    return query


def error_from_exception(exc: Exception) -> ApiError:
    """Map what a control request can raise to an :class:`ApiError`."""
    if isinstance(exc, ApiError):
        return exc
    if isinstance(exc, InvalidField):
        return ApiError(400, "invalid_request", str(exc), exc.field)
    if isinstance(exc, PayloadError):
        return ApiError(400, "invalid_request", str(exc))
    if isinstance(exc, RequestRefused):
        error: ErrorReply = exc.error
        status = {"invalid_request": 400, "unavailable": 409, "busy": 503}.get(error.code, 502)
        return ApiError(status, error.code, error.reason)
    if isinstance(exc, NotPermitted):
        return ApiError(403, "not_permitted", str(exc))
    if isinstance(exc, NoAnswer):
        return ApiError(504, "timeout", str(exc))
    if isinstance(exc, ClientError):
        return ApiError(502, "internal", str(exc))
    raise exc

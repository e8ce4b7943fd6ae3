"""Client errors: the server's RFC 9457 problem, or no answer at all."""

from __future__ import annotations

__all__ = ["ClientError", "ProblemError", "ServiceUnreachable"]


class ClientError(Exception):
    """Base of every error the client raises."""


class ProblemError(ClientError):
    """The service answered with an error; ``status``, ``title`` and ``detail`` are its
    problem members (``problem`` the whole body)."""

    def __init__(self, status: int, title: str, detail: str, problem: dict | None = None):
        super().__init__(f"{status} {title}: {detail}")
        self.status, self.title, self.detail = status, title, detail
        self.problem = problem or {}


class ServiceUnreachable(ClientError):
    """No answer after every retry (connection refused, reset or timed out)."""

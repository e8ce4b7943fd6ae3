"""Client errors: the server's RFC 9457 problem, no answer at all, or a tree build that
failed or outlasted the caller's deadline."""

from __future__ import annotations

from typing import Any

__all__ = ["BuildFailed", "BuildTimeout", "ClientError", "ProblemError", "ServiceUnreachable"]


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


class BuildFailed(ClientError):
    """The service could not build the uploaded mesh's tree: ``reason`` is its message,
    ``cause`` its kind ("engine": the mesh cannot be built; "memory"; "cancelled": every
    uploader deleted it; "lost"; "internal"), ``job_url`` the job. Upload the mesh again
    to retry."""

    def __init__(self, reason: str, cause: str | None, job_url: str, job: Any = None) -> None:
        super().__init__(f"the tree build failed ({cause}): {reason} [{job_url}]")
        self.reason, self.cause, self.job_url, self.job = reason, cause, job_url, job


class BuildTimeout(ClientError):
    """The tree was not built within the caller's ``timeout``; the build goes on: keep
    polling ``job_url`` (``client.wait_for_mesh(error.job)`` or ``client.job(url)``).
    ``job`` is the last status seen. ``job_url`` is None when the deadline passed before
    the service answered the upload itself: then uploading the same mesh again joins its
    build if the service had accepted it."""

    def __init__(self, timeout: float, job_url: str | None, job: Any = None) -> None:
        if job_url is None:
            text = (
                f"the service did not answer the upload within {timeout:g} s; upload the"
                " mesh again to join its build if it was accepted"
            )
        else:
            status = getattr(job, "status", "unfinished")
            text = (
                f"the tree was not built within {timeout:g} s (job {status}); it goes on:"
                f" poll {job_url}"
            )
        super().__init__(text)
        self.timeout, self.job_url, self.job = timeout, job_url, job

"""Request dependencies: the service's state (:class:`app.service.state.AppState`), the
settings, the token check."""

from __future__ import annotations

import secrets
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from app.service.settings import Settings
from app.service.state import AppState


def get_state(request: Request) -> AppState:
    state: AppState | None = getattr(request.app.state, "aar", None)
    if state is None:
        raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE, "service is starting")
    return state


_bearer = HTTPBearer(auto_error=False)


def request_settings(request: Request) -> Settings:
    """The app's settings (``create_app`` keeps them in ``app.state``; the service's state has
    them too). An app without either (a bare router in a test) reads the environment."""
    settings: Settings | None = getattr(request.app.state, "settings", None)
    if settings is None:
        state: AppState | None = getattr(request.app.state, "aar", None)
        settings = state.settings if state is not None else Settings()
    return settings


def require_token(
    request: Request,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> None:
    """Mutating endpoints: if ``AAR_TOKEN`` is set, demand ``Authorization: Bearer <token>``.

    ``app.server.security.RequestGuard`` checks the same before the body is read; this
    dependency stays on every mutating route as a second line (and for apps without the
    guard).
    """
    token = request_settings(request).token
    if not token:
        return
    if credentials is None or not secrets.compare_digest(
        credentials.credentials.encode(), token.encode()
    ):
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED,
            "missing or wrong bearer token",
            headers={"WWW-Authenticate": "Bearer"},
        )


StateDep = Annotated[AppState, Depends(get_state)]

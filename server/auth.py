"""Admin routes need ``Authorization: Bearer <RBA_ADMIN_TOKEN>`` (compared in constant time)."""

from __future__ import annotations

import hmac
from typing import Annotated

from fastapi import Depends, HTTPException, Request

from server.deps import ServicesDep


def require_admin(request: Request, svc: ServicesDep) -> None:
    """503 when no token is configured, 401 when the request's is missing or wrong."""
    token = svc.settings.admin_token
    if not token:
        raise HTTPException(503, "admin disabled: set RBA_ADMIN_TOKEN to enable the admin routes")
    scheme, _, given = request.headers.get("authorization", "").partition(" ")
    if scheme.lower() != "bearer" or not given:
        raise HTTPException(401, "admin token required: send 'Authorization: Bearer <token>'",
                            headers={"WWW-Authenticate": "Bearer"})
    if not hmac.compare_digest(given.strip().encode(), token.encode()):
        raise HTTPException(401, "wrong admin token", headers={"WWW-Authenticate": "Bearer"})


AdminDep = Annotated[None, Depends(require_admin)]

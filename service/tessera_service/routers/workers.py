"""Admin actions on workers: disable one (it takes no new task), enable it again, and take
it off the blocklists of the jobs it failed on. Only an admin (users.User.admin: a name
in TESSERA_API_ADMINS, or the anonymous loopback user of `tessera serve`) may: a worker
serves every user."""
from __future__ import annotations

from fastapi import APIRouter, HTTPException, Path, Request

from ..schemas import BlocklistCleared, WorkerStatus
from ..store import JobStore
from ..users import User
from .farm import list_workers
from .jobs import CurrentUser

router = APIRouter(prefix="/workers", tags=["farm"])
WorkerName = Path(max_length=200, description="the worker's name, as GET /workers lists it")
_ADMIN_ONLY = {403: {"description": "not an admin"}, 404: {"description": "no live worker of that name"}}


def _require_admin(user: User) -> None:
    if not user.admin:
        raise HTTPException(403, "only an admin may change a worker (TESSERA_API_ADMINS)")


def _changed(request: Request, user: User, name: str, disabled: bool) -> WorkerStatus:
    _require_admin(user)
    store: JobStore = request.app.state.store
    if not store.set_worker_disabled(name, disabled):
        raise HTTPException(404, f"no live worker named {name!r}")
    for worker in list_workers(request, user).workers:
        if worker.name == name:
            return worker
    raise HTTPException(404, f"no live worker named {name!r}")  # its heartbeat ran out meanwhile


@router.post("/{name}/disable", response_model=WorkerStatus, responses=_ADMIN_ONLY)
def disable_worker(request: Request, user: CurrentUser, name: str = WorkerName) -> WorkerStatus:
    """The worker takes no new task (the one it renders it finishes and stores); it stays
    alive, beating, until enabled again or stopped."""
    return _changed(request, user, name, True)


@router.post("/{name}/enable", response_model=WorkerStatus, responses=_ADMIN_ONLY)
def enable_worker(request: Request, user: CurrentUser, name: str = WorkerName) -> WorkerStatus:
    return _changed(request, user, name, False)


@router.delete("/{name}/blocklist", response_model=BlocklistCleared,
               responses={403: {"description": "not an admin"}})
def clear_blocklist(request: Request, user: CurrentUser, name: str = WorkerName) -> BlocklistCleared:
    """Takes the worker off the blocklist of every job not yet finished (a job blocklists
    a worker after protocol.BLOCKLIST_AFTER failures there), and forgets those failures:
    after fixing the machine, it takes those jobs' tiles again."""
    _require_admin(user)
    store: JobStore = request.app.state.store
    return BlocklistCleared(worker=name, jobs=store.clear_blocklist(name))

"""Who may use the console: accounts, password hashes, sessions and the sign-in back-off.

No web code and no clock of its own (times are arguments, as in :mod:`spec.auth`): the
middleware in :mod:`welding.console.access` asks these objects, per request, who is signed in.

- **Accounts** live in a users file (``--users FILE``, JSON, written atomically by
  ``welding console adduser``): name, role and an scrypt hash (``hashlib.scrypt``, stdlib).
- **The sign-in URL**: at start the console prints a URL with a random one-time token (as
  Jupyter Server does); opening it signs the browser in as the operator at the terminal
  (user ``token``) and a fresh URL is printed for the next browser.
- **Sessions** are random ids in an HttpOnly, SameSite=Strict cookie, each with its own CSRF
  token, ending ``lifetime`` seconds after sign-in.
- **Failed sign-ins** are slowed per address by the same back-off RobotSocket uses for
  TakeControl (:class:`spec.auth.AuthBackoff`).
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
import secrets
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from spec.auth import AuthBackoff, tokens_equal
from spec.files import write_atomically

__all__ = [
    "ROLES",
    "Account",
    "Role",
    "Session",
    "Sessions",
    "SignInRefused",
    "UsersError",
    "add_user",
    "hash_password",
    "load_users",
    "verify_password",
]

Role = Literal["viewer", "operator"]
#: A viewer sees status and the sensor view; an operator may also act (issue 28 item 2).
ROLES: tuple[Role, ...] = ("viewer", "operator")
#: The user a browser signed in with the printed sign-in URL is (the person at the terminal).
TOKEN_USER = "token"
#: scrypt cost: 16 MiB and ~50 ms per check, as hashlib's docs and OWASP suggest for logins.
SCRYPT_N, SCRYPT_R, SCRYPT_P = 2**14, 8, 1
NAME_CHARS = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_.-@")


class UsersError(ValueError):
    """A users file or account that cannot be used (the message names the problem)."""


class SignInRefused(Exception):
    """A sign-in refused; ``status`` 401 (wrong name or password) or 429 (slowed down)."""

    def __init__(self, message: str, status: int, retry_after: float = 0.0) -> None:
        super().__init__(message)
        self.status = status
        self.retry_after = retry_after


def _b64(raw: bytes) -> str:
    return base64.b64encode(raw).decode("ascii")


def hash_password(password: str, salt: bytes | None = None) -> str:
    """``scrypt$N$r$p$salt$hash`` (base64) of ``password`` with a random 16-byte salt."""
    salt = secrets.token_bytes(16) if salt is None else salt
    digest = hashlib.scrypt(
        password.encode("utf-8"), salt=salt, n=SCRYPT_N, r=SCRYPT_R, p=SCRYPT_P, dklen=32
    )
    return f"scrypt${SCRYPT_N}${SCRYPT_R}${SCRYPT_P}${_b64(salt)}${_b64(digest)}"


def verify_password(password: str, stored: str) -> bool:
    """Whether ``password`` matches ``stored`` (from :func:`hash_password`); constant time."""
    try:
        scheme, n, r, p, salt, digest = stored.split("$")
        if scheme != "scrypt":
            return False
        want = base64.b64decode(digest, validate=True)
        got = hashlib.scrypt(
            password.encode("utf-8"),
            salt=base64.b64decode(salt, validate=True),
            n=int(n),
            r=int(r),
            p=int(p),
            dklen=len(want),
            maxmem=256 * 1024 * 1024,
        )
    except (ValueError, TypeError):  # a hash broken by hand never matches
        return False
    return hmac.compare_digest(got, want)


@dataclass(frozen=True)
class Account:
    name: str
    role: Role
    password_hash: str


def _check_name(name: str) -> None:
    if not (1 <= len(name) <= 64) or not set(name) <= NAME_CHARS or name == TOKEN_USER:
        raise UsersError(
            f"bad user name {name!r}: 1-64 letters, digits or '_.-@' (and not {TOKEN_USER!r})"
        )


def load_users(path: str | Path) -> dict[str, Account]:
    """The accounts in ``path``: ``{"users": [{"name", "role", "password"}, ...]}``;
    UsersError naming the file and the problem."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UsersError(f"users file {path} does not exist (welding console adduser)") from None
    except OSError as exc:
        raise UsersError(f"cannot read users file {path}: {exc.strerror or exc}") from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise UsersError(f"users file {path} is not JSON: {exc}") from None
    rows = data.get("users") if isinstance(data, dict) else None
    if not isinstance(rows, list):
        raise UsersError(f'users file {path}: expected {{"users": [...]}}')
    users: dict[str, Account] = {}
    for i, row in enumerate(rows):
        where = f"users file {path}, entry {i + 1}"
        if not isinstance(row, dict) or set(row) != {"name", "role", "password"}:
            raise UsersError(f"{where}: expected name, role and password (a hash)")
        name, role, pw = row["name"], row["role"], row["password"]
        if not isinstance(name, str) or not isinstance(pw, str):
            raise UsersError(f"{where}: name and password must be strings")
        try:
            _check_name(name)
        except UsersError as exc:
            raise UsersError(f"{where}: {exc}") from None
        if role not in ROLES:
            raise UsersError(f"{where}: role must be one of {', '.join(ROLES)}")
        if not pw.startswith("scrypt$"):
            raise UsersError(f"{where}: password must be an scrypt hash (adduser writes one)")
        if name in users:
            raise UsersError(f"{where}: user {name!r} appears twice")
        users[name] = Account(name, role, pw)
    return users


def add_user(path: str | Path, name: str, role: Role, password: str) -> bool:
    """Add ``name`` to the users file (created if missing), or replace its role and password;
    True when the user was new. The file is rewritten atomically."""
    _check_name(name)
    if role not in ROLES:
        raise UsersError(f"role must be one of {', '.join(ROLES)}")
    if len(password) < 8:
        raise UsersError("the password is too short (at least 8 characters)")
    users = load_users(path) if Path(path).exists() else {}
    new = name not in users
    users[name] = Account(name, role, hash_password(password))
    rows = [{"name": a.name, "role": a.role, "password": a.password_hash} for a in users.values()]
    write_atomically(path, json.dumps({"users": rows}, indent=2) + "\n")
    return new


@dataclass
class Session:
    """One signed-in browser: ``sid`` is the cookie's value, ``csrf`` the token every
    state-changing request carries in ``X-CSRF-Token``; ``expires`` is on the sessions' clock."""

    sid: str
    user: str
    role: Role
    csrf: str
    address: str
    expires: float


class Sessions:
    """The console's accounts, its one-time sign-in token and the signed-in sessions.

    ``users``: the accounts (may be empty: then only the sign-in URL signs in); ``lifetime``:
    seconds a session lasts. Thread-safe: requests and the status stream ask at once."""

    def __init__(self, users: dict[str, Account], *, lifetime: float = 12 * 3600.0) -> None:
        if lifetime <= 0:
            raise ValueError("lifetime must be > 0")
        self.users = users
        self.lifetime = lifetime
        self._lock = threading.Lock()
        self._sessions: dict[str, Session] = {}
        self._backoff = AuthBackoff(base=1.0, cap=30.0, threshold=3)
        self._token = secrets.token_urlsafe(32)

    @property
    def token(self) -> str:
        """The sign-in URL's token, valid once."""
        with self._lock:
            return self._token

    def _open(self, user: str, role: Role, address: str, now: float) -> Session:
        s = Session(
            secrets.token_urlsafe(32), user, role, secrets.token_urlsafe(32), address,
            now + self.lifetime,
        )  # fmt: skip
        self._sessions[s.sid] = s
        return s

    def _refuse_if_slowed(self, address: str, now: float) -> None:
        wait = self._backoff.wait(address, now)
        if wait > 0:
            raise SignInRefused(
                f"too many failed sign-ins from {address}: try again in {wait:.0f} s", 429, wait
            )

    def _failed(self, address: str, now: float, why: str) -> SignInRefused:
        count, delay = self._backoff.failed(address, now)
        more = f" (failure {count}; next try in {delay:.0f} s)" if delay else ""
        return SignInRefused(f"{why}{more}", 401, delay)

    def sign_in_token(self, token: str, address: str, now: float) -> Session:
        """A session for the holder of the sign-in URL's token; a fresh token replaces it."""
        with self._lock:
            self._refuse_if_slowed(address, now)
            if not tokens_equal(token, self._token):
                raise self._failed(address, now, "the sign-in link is wrong or was used already")
            self._backoff.succeeded(address)
            self._token = secrets.token_urlsafe(32)  # one-time: a copied URL is worth nothing
            return self._open(TOKEN_USER, "operator", address, now)

    def sign_in_password(self, name: str, password: str, address: str, now: float) -> Session:
        """A session for ``name`` when ``password`` matches its hash."""
        with self._lock:
            self._refuse_if_slowed(address, now)
            account = self.users.get(name)
        # ~50 ms of scrypt outside the lock; an unknown name costs as much as a known one
        ok = verify_password(password, account.password_hash if account else _DUMMY_HASH)
        with self._lock:
            if account is None or not ok:
                raise self._failed(address, now, "wrong user name or password")
            self._backoff.succeeded(address)
            return self._open(account.name, account.role, address, now)

    def get(self, sid: str | None, now: float) -> Session | None:
        """The live session with id ``sid``; None when there is none or it has expired."""
        if not sid:
            return None
        with self._lock:
            s = self._sessions.get(sid)
            if s is not None and now >= s.expires:
                del self._sessions[sid]
                return None
            return s

    def end(self, sid: str) -> None:
        with self._lock:
            self._sessions.pop(sid, None)


_DUMMY_HASH = hash_password("", salt=b"\0" * 16)

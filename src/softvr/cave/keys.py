"""CURVE keys of a render cluster: made on first use, each bound to one node name.

A key folder (default :func:`default_folder`, mode 0700) holds:

=========================  ================================================================
``master.key``             the master's public key (copied to every node's host)
``master.key_secret``      the master's secret key (0600; only on the master's host)
``nodes/NAME.key``         node NAME's public key, and ``nodes/NAME.key_secret`` (0600) its
                           secret, both made on the node's own host
``authorized/NAME.key``    a public key the master accepts, for node NAME only: the file's
                           name is the one name that key may use
=========================  ================================================================

Only public keys travel: ``master.key`` to each node host, each node's ``nodes/NAME.key`` to
the master's ``authorized/NAME.key``. On one host (``softvr cave local``, tests) one folder
holds everything and a node authorizes its own new key there, since that folder also holds the
master's secret (whoever may write into it could read that secret anyway).

Files are in ZeroMQ's certificate format (:func:`zmq.auth.load_certificate` reads them),
written atomically (a temporary file created with its final mode, then renamed). A secret key
file that others can read is refused, as ssh refuses such a private key.
"""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path

import zmq
import zmq.auth

from softvr.errors import InputError

__all__ = ["authorized_names", "check_name", "default_folder", "make_keys", "master_pair", "master_public",
           "node_pair"]

_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}")
_KEY_FILE_LIMIT = 4096  # [bytes]; a certificate is about 300


def default_folder() -> Path:
    """``$SOFTVR_CAVE_KEYS``, else ``$XDG_CONFIG_HOME/softvr/cave-keys``, else
    ``~/.config/softvr/cave-keys``."""
    if os.environ.get("SOFTVR_CAVE_KEYS"):
        return Path(os.environ["SOFTVR_CAVE_KEYS"])
    config = os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config"
    return Path(config) / "softvr" / "cave-keys"


def check_name(name: str) -> str:
    """A node name is also a key file's name: 1..64 of letters, digits, ``_ . -``, not
    starting with ``.`` or ``-``."""
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise InputError("node name", "1..64 letters, digits, '_', '.', '-' (not starting with '.' or '-')",
                         repr(name))
    return name


def _mkdir(folder: Path) -> Path:
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    if not folder.is_dir():
        raise InputError("key folder", "a folder", f"{folder} (not a folder)")
    return folder


def _write(path: Path, text: str, mode: int) -> None:
    """Write ``text`` to ``path`` atomically, the file having ``mode`` from its creation on
    (never briefly readable by others)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    try:
        with os.fdopen(fd, "w", encoding="ascii") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, mode)  # os.open's mode is reduced by the umask; keep exactly this one
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _certificate(name: str, public: bytes, secret: bytes | None = None) -> str:
    lines = [f"#   ZeroMQ CURVE {'secret' if secret else 'public'} certificate for softvr cave {name}",
             "metadata", f'    name = "{name}"', "curve", f'    public-key = "{public.decode()}"']
    if secret:
        lines.append(f'    secret-key = "{secret.decode()}"')
    return "\n".join(lines) + "\n"


def _load(path: Path, what: str, *, secret: bool) -> tuple[bytes, bytes | None]:
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise InputError(what, f"a CURVE key file at {path} (softvr cave keys)", "no such file") from None
    if not stat.S_ISREG(info.st_mode) or info.st_size > _KEY_FILE_LIMIT:
        raise InputError(what, f"a regular key file of at most {_KEY_FILE_LIMIT} bytes", f"{path}")
    if secret and info.st_mode & 0o077:
        raise InputError(what, "a secret key file only its owner can read (chmod 600)",
                         f"{path} with mode {stat.S_IMODE(info.st_mode):04o}")
    try:
        public, secret_key = zmq.auth.load_certificate(str(path))
    except (OSError, ValueError) as exc:
        raise InputError(what, "a ZeroMQ CURVE certificate", f"{path}: {exc}") from None
    if len(public) != 40 or (secret and (secret_key is None or len(secret_key) != 40)):
        raise InputError(what, "40-character Z85 CURVE keys", str(path))
    return public, secret_key


def _pair(folder: Path, stem: str, name: str) -> tuple[bytes, bytes]:
    """The key pair ``stem.key`` / ``stem.key_secret`` in ``folder``, made on first use."""
    secret_path = folder / f"{stem}.key_secret"
    if not secret_path.exists():
        public, secret = zmq.curve_keypair()
        _write(secret_path, _certificate(name, public, secret), 0o600)
        _write(folder / f"{stem}.key", _certificate(name, public), 0o644)
    public_key, secret_key = _load(secret_path, f"{name} secret key", secret=True)
    assert secret_key is not None  # read with secret=True
    return public_key, secret_key


def master_pair(folder=None) -> tuple[bytes, bytes]:
    """The master's (public, secret) CURVE keys [Z85] in ``folder``, made on first use."""
    return _pair(_mkdir(Path(folder or default_folder())), "master", "master")


def master_public(folder=None) -> bytes:
    """The master's public key [Z85] as a node holds it (``master.key``)."""
    folder = Path(folder or default_folder())
    return _load(folder / "master.key", "master public key (copy master.key from the master's key folder)",
                 secret=False)[0]


def node_pair(folder, name: str) -> tuple[bytes, bytes]:
    """Node ``name``'s (public, secret) CURVE keys [Z85], made on first use on this host; in
    a folder that also holds the master's secret (one host) the new key is authorized too."""
    folder = Path(folder or default_folder())
    check_name(name)
    public, secret = _pair(_mkdir(folder / "nodes"), name, name)
    authorized = folder / "authorized" / f"{name}.key"
    if (folder / "master.key_secret").exists() and not authorized.exists():
        _mkdir(authorized.parent)
        _write(authorized, _certificate(name, public), 0o644)
    return public, secret


def authorized_names(folder=None) -> dict[bytes, str]:
    """Public key [Z85] -> the node name it may use, from ``authorized/NAME.key``; a key
    authorized under two names is refused."""
    folder = _mkdir(Path(folder or default_folder()) / "authorized")
    names: dict[bytes, str] = {}
    for path in sorted(folder.glob("*.key")):
        name = check_name(path.stem)
        public, _ = _load(path, f"authorized key of {name}", secret=False)
        if public in names:
            raise InputError(f"authorized key of {name}", "one node name per key",
                             f"the key of {names[public]!r} again", source=str(path))
        names[public] = name
    return names


def make_keys(folder=None, nodes=(), *, master: bool = True) -> Path:
    """``softvr cave keys``: the master's pair (``master``) and each of ``nodes``' pairs in
    ``folder``, each made only if missing; returns the folder."""
    folder = _mkdir(Path(folder or default_folder()))
    if master:
        master_pair(folder)
    for name in nodes:
        node_pair(folder, name)
    return folder

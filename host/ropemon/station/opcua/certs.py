"""Who may connect to the OPC UA face: the server's own certificate (made on first start), the
client certificates' trust list, and the logins on the station's users file.

asyncua and cryptography are imported inside the calls (the `opcua` extra).
"""
from __future__ import annotations

import datetime
import logging
import socket
from pathlib import Path
from typing import Any

from ropemon.station import files

log = logging.getLogger("ropemon.station.opcua")   # the face's one logger, as before it was a package

CERT_FILE, KEY_FILE = "server.der", "server-key.pem"
CERT_DAYS = 5 * 365


# -- the client trust list -------------------------------------------------------------------


class TrustList:
    """The client certificates the server accepts: the DER or PEM files in the `trusted` folder,
    read again at each check (moving a certificate in or out needs no restart). A certificate is
    trusted when it is one of them, byte for byte, and within its validity period; no CA chains
    and no revocation lists. A refused certificate is written (DER) to the `rejected` folder,
    `<common name> [<SHA-1 thumbprint>].der`, for an engineer to move into `trusted`; at most
    REJECTED_MAX files are kept there."""

    REJECTED_MAX = 200

    def __init__(self, trusted: Path, rejected: Path) -> None:
        self.trusted, self.rejected = trusted, rejected
        trusted.mkdir(parents=True, exist_ok=True)
        rejected.mkdir(parents=True, exist_ok=True)

    def _fingerprints(self) -> set[bytes]:
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes
        out = set()
        for f in sorted(self.trusted.iterdir()):
            if not f.is_file() or f.suffix.lower() not in (".der", ".pem", ".crt", ".cer"):
                continue
            try:
                data = f.read_bytes()
                c = (x509.load_pem_x509_certificate(data) if data.lstrip().startswith(b"-----BEGIN")
                     else x509.load_der_x509_certificate(data))
            except (ValueError, OSError) as e:
                log.warning("OPC UA trust list: %s is not a certificate (%s)", f, e)
                continue
            out.add(c.fingerprint(hashes.SHA256()))
        return out

    def why_refused(self, der: bytes | None) -> str | None:
        """None when the certificate (DER) is trusted, else why (and it is written to `rejected`)."""
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes
        if not der:
            return "no client certificate"
        try:
            c = x509.load_der_x509_certificate(bytes(der))
        except ValueError:
            return "not a certificate"
        if c.fingerprint(hashes.SHA256()) not in self._fingerprints():
            self._reject(c)
            return f"certificate {_cert_name(c)!r} is not in {self.trusted}"
        now = datetime.datetime.now(datetime.timezone.utc)
        if not c.not_valid_before_utc <= now <= c.not_valid_after_utc:
            return f"certificate {_cert_name(c)!r} is outside its validity period"
        return None

    def _reject(self, c: Any) -> None:
        from cryptography.hazmat.primitives import hashes
        from cryptography.hazmat.primitives.serialization import Encoding
        name = "".join(ch if ch.isalnum() or ch in " ._-" else "_" for ch in _cert_name(c))[:64].strip() or "client"
        f = self.rejected / f"{name} [{c.fingerprint(hashes.SHA1()).hex().upper()}].der"   # noqa: S303 (OPC UA thumbprint)
        try:
            if f.exists() or sum(1 for _ in self.rejected.iterdir()) >= self.REJECTED_MAX:
                return
            f.write_bytes(c.public_bytes(Encoding.DER))
        except OSError as e:
            log.warning("OPC UA: could not keep the rejected certificate %s: %s", f, e)


def _cert_name(c: Any) -> str:
    from cryptography import x509
    cn = c.subject.get_attributes_for_oid(x509.NameOID.COMMON_NAME)
    return str(cn[0].value) if cn else c.subject.rfc4514_string()


def _certificate_check(trust: TrustList) -> Any:
    """asyncua's certificate validator at CreateSession: BadCertificateUntrusted for a client
    certificate not in the trust list."""
    async def check(cert: Any, app: Any) -> None:
        from asyncua import ua
        from asyncua.common.utils import ServiceError
        from cryptography.hazmat.primitives.serialization import Encoding
        why = trust.why_refused(cert.public_bytes(Encoding.DER))
        if why is not None:
            log.warning("OPC UA client %s refused: %s", getattr(app, "ApplicationUri", "?"), why)
            raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)
    return check


# -- the logins -------------------------------------------------------------------------------


class _UserManager:
    """asyncua's user manager on the station's users file (`ropemon.station.users.Users`, the
    web face's: one file, one set of roles): a listed user with the right password, or, with
    allow_anonymous, a client without a name, as a viewer."""

    def __init__(self, users: Any, allow_anonymous: bool, trust: TrustList | None = None) -> None:
        self.users, self.allow_anonymous, self.trust = users, allow_anonymous, trust

    def get_user(self, iserver: Any, username: str | None = None, password: str | None = None,
                 certificate: Any = None) -> Any:
        from asyncua.crypto.permission_rules import User, UserRole
        if self.trust is not None:
            # `certificate` is the secure channel's own client certificate: the one CreateSession
            # names (checked by _check_client) could be another's
            why = self.trust.why_refused(certificate)
            if why is not None:
                from asyncua import ua
                from asyncua.common.utils import ServiceError
                log.warning("OPC UA session refused: %s", why)
                raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)
        if username is None and password is None:   # an anonymous token (over a secure channel: with its certificate)
            return User(role=UserRole.User, name=None) if self.allow_anonymous else None
        if self.users is None or not username or password is None:
            return None
        u, why = self.users.login(username, password)
        if u is None:
            log.warning("OPC UA login refused for %r: %s", username, why)
            return None
        return User(role=UserRole.User, name=u.name)


# -- certificate ---------------------------------------------------------------------


def ensure_certificate(folder: Path, host: str) -> tuple[Path, Path]:
    """The server's certificate (DER) and key (PEM, mode 0600) in `folder`, made self-signed on
    first start (RSA 2048, SHA-256, 5 years; the application URI urn:ropemon:station:HOSTNAME
    and the endpoint's host in its subject alternative names)."""
    from asyncua.crypto.cert_gen import (dump_private_key_as_pem, generate_private_key,
                                         generate_self_signed_app_certificate)
    from cryptography import x509
    from cryptography.hazmat.primitives.serialization import Encoding
    from cryptography.x509.oid import ExtendedKeyUsageOID

    folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    cert, key = folder / CERT_FILE, folder / KEY_FILE
    if cert.is_file() and key.is_file():
        if key.stat().st_mode & 0o077:
            raise RuntimeError(f"{key}: readable by others (mode {key.stat().st_mode & 0o777:o}): chmod 600 it")
        return cert, key
    pk = generate_private_key()
    uri = f"urn:ropemon:station:{socket.gethostname()}"
    names: list[x509.GeneralName] = [x509.UniformResourceIdentifier(uri), x509.DNSName(socket.gethostname())]
    if host and host != socket.gethostname():
        try:
            import ipaddress
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    c = generate_self_signed_app_certificate(pk, "ropemon station", {"organizationName": "ropemon"}, names,
                                             extended=[ExtendedKeyUsageOID.SERVER_AUTH,
                                                       ExtendedKeyUsageOID.CLIENT_AUTH], days=CERT_DAYS)
    files.write_private(key, dump_private_key_as_pem(pk))
    cert.write_bytes(c.public_bytes(Encoding.DER))
    return cert, key


def certificate_uri(path: Path) -> str | None:
    """The application URI in a DER certificate's subject alternative names."""
    from cryptography import x509
    try:
        c = x509.load_der_x509_certificate(path.read_bytes())
        uris = c.extensions.get_extension_for_class(x509.SubjectAlternativeName).value.get_values_for_type(
            x509.UniformResourceIdentifier)
    except (ValueError, OSError, x509.ExtensionNotFound):
        return None
    return uris[0] if uris else None
